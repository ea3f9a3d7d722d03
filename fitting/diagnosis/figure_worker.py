"""The report's figures drawn in a separate process while the posterior check samples.

The command line's ``diagnose --report`` hands the figures' plans
(:func:`fitting.diagnosis.report_figures.figure_plans`: plain arrays and text) to a child
Python process as soon as the verdict is final (``diagnose(on_verdict=...)``); the child
draws them with :mod:`fitting.diagnosis.figure_render` into a private temporary folder
while this process samples the posterior, and :func:`fitting.diagnosis.report.write_report`
moves them into the report. The figures do not show the posterior, so nothing differs
but the time: on the bundled example the figures took ~1 s after the diagnosis, about
what the posterior takes; drawn beside it, a warm run is 0.25-0.65 s shorter (not the whole
second: the posterior's XLA threads keep the second core partly busy, benchmarks/LATENCY.md).
A thread would not do: matplotlib holds the interpreter lock, and JAX programs must not be
called from two threads at once (:mod:`fitting.diagnosis.effect_posterior`). The child runs
at ``nice`` 10, so the diagnosis keeps priority.

The child never imports JAX (it would add a second of start-up): it is this file run as
a script, and it imports the three modules it needs (:mod:`fitting.diagnosis.figure_render`,
:mod:`cstiffjax.plots.scene`, :mod:`cstiffjax.io.atomic`: numpy, matplotlib and the
standard library) without running the packages' ``__init__`` files, which import JAX.

Whatever goes wrong in the child (it cannot start, it dies, it reports nothing), the
report draws its figures in this process as before (:meth:`FigureWorker.move_into` returns
None); a figure that cannot be drawn is named in the report's warnings either way.
"""

import json
import os
import pickle
import shutil
import subprocess
import sys
import tempfile
import threading
import types
from pathlib import Path

_ROOT = Path(__file__).resolve().parents[2]  # the folder holding the packages cstiffjax and fitting
# the packages whose __init__ the child skips (each imports JAX, or a package that does)
_LIGHT = ("cstiffjax", "cstiffjax.io", "cstiffjax.plots", "fitting", "fitting.diagnosis")
TIMEOUT_S = 300.0  # the most the report waits for the child before drawing the figures itself


class FigureWorker:
    """A child process that draws the report's figures (see the module). Use as a context
    manager: on leaving it the child is stopped and its temporary folder removed, whatever
    happened.

    - :meth:`start`: launch the child (it imports matplotlib and waits); optional,
      :meth:`submit` launches it when needed.
    - :meth:`submit` ``(diagnosis)``: compute the plans here, send them; the call returns at once.
    - :meth:`move_into` ``(out_dir, problems)``: wait for the child, move its figures into
      ``out_dir``; the file names, or None when the child failed (then draw them here).
    """

    def __init__(self):
        self._proc, self._folder = None, None
        self.problems = []  # figures whose plan could not be computed (named like best_effort)
        self.submitted = False

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        """Stop the child (if still running) and remove its temporary folder."""
        if self._proc is not None:
            if self._proc.poll() is None:
                self._proc.kill()
            self._proc.wait()
            for pipe in (self._proc.stdin, self._proc.stdout):
                if not pipe.closed:
                    pipe.close()
            self._proc = None
        if self._folder is not None:
            self._folder.cleanup()
            self._folder = None

    def start(self) -> bool:
        """Launch the child unless it runs already; False when it cannot be launched."""
        if self._proc is None:
            try:
                self._proc = subprocess.Popen([sys.executable, str(Path(__file__).resolve())],
                                              stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                              env={**os.environ, "MPLBACKEND": "Agg"})
            except OSError:
                return False
        return True

    def submit(self, diagnosis) -> None:
        """Compute the figures' plans of ``diagnosis`` (a plan that fails is named in
        :attr:`problems`) and hand them to the child (launched if needed)."""
        from fitting.diagnosis.report_figures import figure_plans

        plans = figure_plans(diagnosis, self.problems)
        if not self.start():
            return
        self._folder = tempfile.TemporaryDirectory(prefix="cstiffjax-figures-")
        try:
            pickle.dump({"folder": self._folder.name, "plans": plans}, self._proc.stdin,
                        protocol=pickle.HIGHEST_PROTOCOL)
            self._proc.stdin.close()
            self.submitted = True
        except OSError:  # the child is gone: the report draws the figures itself
            self.submitted = False

    def move_into(self, out_dir, problems: list) -> list[str] | None:
        """Wait for the child; move the figures it drew into ``out_dir``, add the problems
        (figures not drawn) to ``problems`` and return the file names written, as
        :func:`~fitting.diagnosis.report_figures.write_figures` does. None (nothing moved,
        nothing added) when nothing was submitted or the child failed: draw them here."""
        if not self.submitted:
            return None
        timer = threading.Timer(TIMEOUT_S, self._proc.kill)  # a child that hangs: draw here
        timer.start()
        try:  # a blocking read to the child's end (Popen.wait with a timeout polls, up to 50 ms late)
            out = self._proc.stdout.read()
            answer = json.loads(out) if self._proc.wait() == 0 else None
        except ValueError:
            answer = None
        finally:
            timer.cancel()
        self.submitted = False
        if not isinstance(answer, dict):
            return None
        for name in answer["files"]:
            shutil.move(os.path.join(self._folder.name, name), Path(out_dir) / name)
        problems.extend([*self.problems, *answer["problems"]])
        return [*answer["files"]]


def _light_imports() -> None:
    """Make ``import fitting.diagnosis.figure_render`` (and the two modules it imports) find
    the files beside this one without running the packages' ``__init__`` files."""
    if sys.path and Path(sys.path[0]).resolve() == Path(__file__).resolve().parent:
        sys.path.pop(0)  # a script's folder comes first on the path: no module here may shadow another
    for name in _LIGHT:
        package = types.ModuleType(name)
        package.__path__ = [str(_ROOT.joinpath(*name.split(".")))]
        sys.modules[name] = package


def main() -> int:
    """The child: read ``{folder, plans}`` (a pickle) from stdin, draw every plan into
    ``folder`` and print ``{files, problems, jax}`` (JSON) on stdout (``jax``: whether JAX
    was imported after all, which the tests check it never is). A figure that fails is a
    problem; anything else (an ``OSError``, bad input) exits non-zero and the report draws
    the figures itself."""
    _light_imports()
    if hasattr(os, "nice"):
        os.nice(10)  # the parent's posterior comes first: this process takes the idle core time
    import matplotlib.pyplot  # noqa: F401  (imported while the parent computes)

    from fitting.diagnosis.figure_render import draw_plans

    job = pickle.load(sys.stdin.buffer)
    problems = []
    files = draw_plans(job["plans"], job["folder"], problems)
    json.dump({"files": files, "problems": problems, "jax": "jax" in sys.modules}, sys.stdout)
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except OSError:  # a full disk: no traceback here; the report draws the figures itself and names the error
        sys.exit(1)
