"""User-facing behaviour: compilation cache location, progress bars, automatic
posterior chain length, the short diagnose summary."""

import ast
import io
import os
import re
import subprocess
import sys

import numpy as np
import pytest

from cstiffjax.core import progress
from cstiffjax.runtime.cache import cache_dir, enable_compilation_cache


# ------------------------------------------------------------------ cache
def test_cache_dir_default_is_under_home_cache(monkeypatch, tmp_path):
    monkeypatch.setenv("HOME", str(tmp_path))
    assert cache_dir({}) == tmp_path / ".cache" / "cstiffjax" / "jax"


def test_cache_dir_respects_xdg_and_env_var(tmp_path):
    assert cache_dir({"XDG_CACHE_HOME": str(tmp_path)}) == tmp_path / "cstiffjax" / "jax"
    env = {"XDG_CACHE_HOME": str(tmp_path), "CSTIFFJAX_CACHE_DIR": str(tmp_path / "mine")}
    assert cache_dir(env) == tmp_path / "mine"  # the explicit variable wins
    assert cache_dir({"XDG_CACHE_HOME": "relative/path"}).is_absolute()  # XDG: relative paths are ignored


@pytest.mark.parametrize("value", ["off", "OFF", "0", "false", "no", "none", ""])
def test_cache_can_be_disabled(value, tmp_path):
    assert cache_dir({"CSTIFFJAX_CACHE_DIR": value, "XDG_CACHE_HOME": str(tmp_path)}) is None
    assert enable_compilation_cache(environ={"CSTIFFJAX_CACHE_DIR": value}) is None


def test_import_does_not_enable_the_cache():
    """A fresh interpreter (the test session's own cache is not inherited): importing the
    library leaves JAX's persistent cache off."""
    env = {k: v for k, v in os.environ.items() if k not in ("CSTIFFJAX_CACHE_DIR", "CSTIFFJAX_TEST_CACHE")}
    code = "import fitting.diagnosis.diagnose, cstiffjax.commands.cli, jax; print(jax.config.jax_compilation_cache_dir)"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "None"


def test_start_up_imports_no_plotting_sampling_or_statistics():
    """Building the command line and importing the diagnosis leave matplotlib, emcee,
    scipy.stats and scipy.spatial out (imported where they are used: ~1 s of every
    command's start, benchmarks/LATENCY.md), and optimistix with lineax (imported when a
    solve is traced, which a warm command line never does: 0.15 s,
    :mod:`cstiffjax.cable.newton2`)."""
    code = ("import sys; from cstiffjax.commands import cli; cli.build_parser(); import fitting, "
            "fitting.diagnosis.diagnose, fitting.diagnosis.report; "
            "print(sorted(m for m in ('matplotlib', 'emcee', 'scipy.stats', 'scipy.spatial', 'optimistix', 'lineax') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_emcee_is_imported_without_scipy_stats_and_its_kde_move_still_works():
    """:func:`fitting.posterior.emcee_import.emcee` imports emcee without ``scipy.stats`` (0.4 s of the
    posterior check's start) and removes its finder; emcee's ``KDEMove``, the one user of
    ``scipy.stats``, then imports it on first use and samples; another thread imports
    ``scipy.stats`` meanwhile as usual."""
    code = """
import sys
import numpy as np
from fitting.posterior import emcee_import as _emcee
emcee = _emcee.emcee()
assert 'scipy.stats' not in sys.modules and not any(isinstance(f, _emcee._DeferStats) for f in sys.meta_path)
import emcee as again
assert again is emcee and _emcee.emcee() is emcee
s = emcee.EnsembleSampler(8, 2, lambda x: -0.5 * np.sum(x ** 2), moves=emcee.moves.KDEMove())
s.run_mcmc(np.random.default_rng(0).standard_normal((8, 2)), 10)
assert 'scipy.stats' in sys.modules and s.acceptance_fraction.mean() > 0
print('ok')
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr[-2000:]
    thread = """
import sys, threading
from fitting.posterior import emcee_import as _emcee
finder = _emcee._DeferStats()  # as during emcee's import in the main thread
sys.meta_path.insert(0, finder)
try:
    import scipy.stats
except ImportError:
    got = []
    t = threading.Thread(target=lambda: got.append(float(__import__('scipy.stats').stats.norm.cdf(0.0))))
    t.start(); t.join()
    print('refused here, not there:', got)
"""
    out = subprocess.run([sys.executable, "-c", thread], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.strip() == "refused here, not there: [0.5]", out.stderr[-2000:]


def test_console_script_flushes_its_output_and_returns_the_exit_code(capsys):
    """``cstiffjax`` (:func:`cstiffjax.commands.cli.console`) ends the process without the
    interpreter's teardown: what it printed still arrives whole, and the exit code is
    :func:`~cstiffjax.commands.cli.main`'s."""
    from cstiffjax.commands import cli

    assert cli.main(["check", "tcpr8.toml", "--quiet"]) == 0
    expected = capsys.readouterr().out
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}  # a pipe is block-buffered
    run = subprocess.run([sys.executable, "-m", "cstiffjax.commands.cli", "check", "tcpr8.toml", "--quiet"],
                         capture_output=True, text=True, env=env)
    assert run.returncode == 0 and run.stdout == expected and expected.strip()
    bad = subprocess.run([sys.executable, "-m", "cstiffjax.commands.cli", "check", "no_such_robot.toml"],
                         capture_output=True, text=True, env=env)
    assert bad.returncode == 1 and "no_such_robot.toml" in bad.stderr
    # the atexit handlers still run (a coverage tool's, logging's), and what they print arrives
    code = ("import atexit, sys; from cstiffjax.commands import cli; atexit.register(print, 'handler ran'); "
            "sys.argv = ['cstiffjax', 'check', 'tcpr8.toml', '--quiet']; cli.console()")
    hooked = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert hooked.returncode == 0 and hooked.stdout == expected + "handler ran\n"
    # started with standard output closed (sys.stdout is None): main's exit code, no traceback
    closed = subprocess.run(["sh", "-c", f"'{sys.executable}' -m cstiffjax.commands.cli check tcpr8.toml --quiet >&-"],
                            capture_output=True, text=True, env=env)
    assert closed.returncode == 0 and "Traceback" not in closed.stderr


def test_the_console_script_collects_garbage_less_often():
    """``cstiffjax`` runs its command with :data:`cstiffjax.commands.cli.GC_THRESHOLDS` (fewer
    collections: ~0.7 s of a cold diagnosis); ``main()`` called from Python leaves the
    interpreter's thresholds as they were."""
    import gc

    from cstiffjax.commands import cli

    before = gc.get_threshold()
    assert cli.main(["check", "tcpr8.toml", "--quiet"]) == 0
    assert gc.get_threshold() == before
    code = ("import atexit, gc, sys; from cstiffjax.commands import cli; print('default', gc.get_threshold()); "
            "atexit.register(lambda: print('thresholds', gc.get_threshold())); "
            "sys.argv = ['cstiffjax', 'check', 'tcpr8.toml', '--quiet']; cli.console()")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    lines = run.stdout.splitlines()
    assert run.returncode == 0 and lines[-1] == f"thresholds {cli.GC_THRESHOLDS}", run.stderr
    default = ast.literal_eval(lines[0].removeprefix("default "))  # a fresh interpreter's thresholds
    assert cli.GC_THRESHOLDS[0] > default[0] and cli.GC_THRESHOLDS != default


def test_enable_sets_jax_config_and_restores(tmp_path):
    import jax
    import jax.numpy as jnp

    from cstiffjax.runtime.cache import compilation_cache

    keys = ("jax_compilation_cache_dir", "jax_persistent_cache_min_compile_time_secs",
            "jax_persistent_cache_min_entry_size_bytes")
    old = {k: getattr(jax.config, k) for k in keys}
    with compilation_cache(environ={"CSTIFFJAX_CACHE_DIR": str(tmp_path / "c")}) as folder:
        assert folder == tmp_path / "c"
        assert jax.config.jax_compilation_cache_dir == str(tmp_path / "c")
        assert [getattr(jax.config, k) for k in keys[1:]] == [0.0, 0]
        jax.jit(lambda x: x * 2.0 + 0.125)(jnp.ones(3)).block_until_ready()
        assert any((tmp_path / "c").iterdir())  # even a tiny, fast compile is written
    assert {k: getattr(jax.config, k) for k in keys} == old  # the caller's settings come back


# --------------------------------------------------------------- progress
class _TTY(io.StringIO):
    def isatty(self):
        return True


def _drawn(monkeypatch, stream, **kw):
    monkeypatch.setattr("sys.stderr", stream)
    for _ in progress.bar(range(3), desc="work", **kw):
        pass
    return stream.getvalue()


def test_progress_auto_only_on_a_terminal(monkeypatch):
    assert _drawn(monkeypatch, io.StringIO()) == ""  # not a terminal: silent
    assert "work" in _drawn(monkeypatch, _TTY())  # a terminal: a bar
    assert _drawn(monkeypatch, _TTY(), progress=False) == ""
    assert "work" in _drawn(monkeypatch, io.StringIO(), progress=True)


def test_progress_quiet_mode(monkeypatch):
    with progress.quiet():
        assert _drawn(monkeypatch, _TTY()) == ""
        assert "work" in _drawn(monkeypatch, _TTY(), progress=True)  # an explicit request still draws
    assert "work" in _drawn(monkeypatch, _TTY())  # the previous mode is back


def test_cli_quiet_silences_progress_on_a_terminal(monkeypatch, tmp_path):
    """Every command has --quiet; with it a terminal gets no bar, without it one does; the
    command runs with the compilation cache on, and main() leaves the process (quiet mode,
    JAX cache settings) as it found it."""
    import jax

    from cstiffjax.commands import check, cli

    parser = cli.build_parser()
    for name in cli.COMMANDS:
        sub = parser._subparsers._group_actions[0].choices[name]
        assert any("--quiet" in a.option_strings for a in sub._actions), name
    monkeypatch.setenv("CSTIFFJAX_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr("sys.stderr", _TTY())
    seen = []
    before = jax.config.jax_compilation_cache_dir

    def fake_run(args):
        seen.append((progress.bar(range(2), desc="x").disable, jax.config.jax_compilation_cache_dir))
        return 0

    monkeypatch.setattr(check, "run", fake_run)
    assert cli.main(["check", "tcpr8.toml", "--quiet"]) == 0
    assert cli.main(["check", "tcpr8.toml"]) == 0
    assert seen == [(True, str(tmp_path / "cache")), (False, str(tmp_path / "cache"))]
    assert not progress.is_quiet() and jax.config.jax_compilation_cache_dir == before


# -------------------------------------------------------------- posterior
def test_posterior_chooses_its_length_from_tau():
    """Default nsteps=None: the chain grows until 50 τ are kept (cheap linear model), and a
    cap below what τ asks for gives a chain the summary refuses, naming the steps needed."""
    from fitting.calibration.least_squares import calibrate_model
    from fitting.posterior.sampler import AUTO_FIRST, MIN_TAU_MULTIPLE, ChainTooShortError, sample_posterior

    x = np.linspace(-1.0, 2.0, 20)
    y = 0.7 - 1.2 * x + 0.3 * np.random.default_rng(0).normal(size=x.size)
    fit = calibrate_model(lambda p, u: p["a"] + p["b"] * u, {"a": 0.0, "b": 0.0}, x, y, 0.3)
    post = sample_posterior(fit, nwalkers=8, seed=0, scale=3.0)
    tau = np.max(post.tau)
    assert post.num_steps - post.burn >= MIN_TAU_MULTIPLE * tau
    assert post.num_steps >= AUTO_FIRST
    post.summary()  # does not raise
    capped = sample_posterior(fit, nwalkers=8, seed=0, scale=3.0, min_steps=300, max_steps=400)
    assert capped.num_steps == 400  # τ ≈ 30 steps here: 400 steps hold fewer than 50 τ
    with pytest.raises(ChainTooShortError, match=r"nsteps >= \d+"):
        capped.summary()


def test_chain_extension_rule():
    """Each extension aims 10% beyond 62.5 τ (50 τ kept after a burn-in of a fifth), grows
    the chain by at least half, never beyond the cap; 50 τ kept is the stopping rule."""
    from fitting.posterior.sampler import _next_length, long_enough

    assert _next_length(1000, np.array([30.0, 12.0]), 20000) == int(np.ceil(50 * 30 / 0.8 * 1.1))
    assert _next_length(1000, np.array([5.0]), 20000) == 1500  # at least x1.5
    assert _next_length(1000, np.array([np.nan]), 20000) == 2000  # no estimate yet: double
    assert _next_length(1000, np.array([1000.0]), 5000) == 5000  # the cap
    assert long_enough(2000, 400, np.array([32.0])) and not long_enough(2000, 400, np.array([32.1]))
    assert not long_enough(2000, 400, np.array([np.nan]))


def test_to_device_compiles_nothing_and_keeps_values_and_dtypes():
    """:func:`cstiffjax.core.arrays.to_device` places host values without compiling a conversion
    program (``jnp.asarray`` compiles one per new shape and dtype: the log shows it), with
    the asked dtype and the same values; a device array or a tracer goes through
    ``jnp.asarray`` (under ``jit`` too)."""
    import logging

    import jax
    import jax.numpy as jnp

    from cstiffjax.core.arrays import f64, to_device

    rng = np.random.default_rng(5)
    host = rng.standard_normal((3, 7, 5))  # a shape no other test converts

    def compiles(fn):
        records = []
        handler = logging.Handler()
        handler.emit = lambda r: records.append(r.getMessage())
        logger = logging.getLogger("jax")
        logger.addHandler(handler)
        try:
            with jax.log_compiles():
                out = fn()
        finally:
            logger.removeHandler(handler)
        return out, [m for m in records if m.startswith("Compiling")]

    (a, b, c, d), logs = compiles(lambda: (to_device(host), f64(host.astype(np.float32)), to_device(host > 0, bool),
                                           f64(2)))
    assert logs == []
    assert isinstance(a, jax.Array) and a.dtype == jnp.float64 and np.array_equal(np.asarray(a), host)
    assert b.dtype == jnp.float64 and np.array_equal(np.asarray(b), host.astype(np.float32).astype(np.float64))
    assert c.dtype == jnp.bool_ and np.array_equal(np.asarray(c), host > 0)
    assert d.dtype == jnp.float64 and d.shape == () and float(d) == 2.0
    _, logs = compiles(lambda: jnp.asarray(rng.standard_normal((3, 7, 6))))
    # the capture sees compiles (so the empty list above means something): jnp.asarray of a
    # new shape compiles one in JAX 0.10; if a JAX release stops that, cstiffjax.core.arrays can go
    assert logs, "no compile of jnp.asarray was logged: the capture is broken, or JAX no longer compiles it"
    e = jax.jit(lambda x: to_device(x, jnp.float32) * 2)(jnp.ones(3))
    assert e.dtype == jnp.float32 and np.array_equal(np.asarray(e), np.full(3, 2.0))


def test_help_names_every_effect_and_free_parameter_and_example(capsys):
    """`diagnose --help` lists the whole vocabulary, `fit --help` every free parameter,
    `check --list-examples` what each bundled file is; no Sphinx markup or paper jargon."""
    from cstiffjax.commands.cli import main
    from cstiffjax.examples import DESCRIPTIONS, list_examples
    from fitting.calibration.parameters import CDPR_PARAMETERS
    from fitting.effects import VOCABULARY

    texts = {}
    for command in ("diagnose", "fit"):
        with pytest.raises(SystemExit) as e:
            main([command, "--help"])
        assert e.value.code == 0
        texts[command] = capsys.readouterr().out
    assert all(effect.name in texts["diagnose"] for effect in VOCABULARY)
    assert "discovered corrections" in texts["diagnose"]
    assert all(re.search(rf"\b{name}\b", texts["fit"]) for name in CDPR_PARAMETERS)
    for text in texts.values():
        assert not re.search(r":(func|class|mod|data):`|``|seed 00\d", text)
    assert sorted(DESCRIPTIONS) == list_examples()


@pytest.mark.slow
def test_fit_posterior_says_up_front_how_long(capsys):
    from cstiffjax.commands.cli import main

    code = main(["fit", "example02/robot.toml", "example02/recordings.csv", "--free", "EA", "--posterior",
                 "--walkers", "12", "--steps", "60", "--quiet"])
    out = capsys.readouterr().out
    plan = next(line for line in out.splitlines() if line.startswith("posterior: 12 walkers x 60 steps, about"))
    after = out[out.index(plan) + len(plan):]
    assert "raise --max-chain" in after or "posterior: 12 walkers x 60 steps (burn-in" in after  # the result follows
    assert code == 0


# ------------------------------------------------------------------ start-up and heartbeat
_MODULES = "print(sorted(m for m in ('jax', 'jaxlib', 'numpy', 'equinox', 'tqdm', 'fitting') if m in sys.modules))"


@pytest.mark.parametrize("argv", [["--version"], ["--help"], []])
def test_version_and_help_import_no_jax(argv):
    """``cstiffjax --version`` and ``--help`` answer without importing JAX, NumPy or a command
    module's dependencies (the console script's own path: ``cstiffjax.commands.cli:console``);
    the help still lists every command, ``fitting``'s registered ones too."""
    code = ("import sys; from cstiffjax.commands import cli\n"
            f"sys.argv = ['cstiffjax', *{argv!r}]\n"
            "try:\n    cli.main()\nexcept SystemExit:\n    pass\n" + _MODULES)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip().splitlines()[-1] == "[]", out.stdout[-2000:]
    if argv != ["--version"]:
        for name in ("check", "stiffness", "tensions", "fit", "diagnose", "generate", "cache"):
            assert re.search(rf"^\s+{name}\s+\S", out.stdout, re.M), name
        assert "diagnose" in out.stdout and "calibrate parameters" in out.stdout  # fit's HELP, read, not imported
    else:
        assert out.stdout.startswith("cstiffjax ")


def test_import_cstiffjax_is_lazy_and_still_float64():
    """``import cstiffjax`` imports no JAX; JAX imported afterwards computes in float64; every
    curated name resolves; ``cstiffjax.stiffness`` is the function even once the stiffness
    layer is imported."""
    code = ("import sys, cstiffjax\nassert 'jax' not in sys.modules\n"
            "import cstiffjax.stiffness.css, jax.numpy as jnp\n"
            "assert all(getattr(cstiffjax, n) is not None for n in cstiffjax.__all__)\n"
            "print(jnp.ones(1).dtype, callable(cstiffjax.stiffness), type(cstiffjax.lie).__name__)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["float64", "True", "module"]


def test_help_lines_are_read_from_the_sources_without_importing():
    from cstiffjax.commands import cli

    for name, module in cli.registered_commands().items():
        assert cli._source(module) is not None, module
        text = cli.command_help(module)
        assert isinstance(text, str) and text, name
    assert cli.command_help("fitting.commands.fit") == __import__("fitting.commands.fit", fromlist=["HELP"]).HELP


class _Bar:
    n, total, desc, unit, postfix = 3, 12, "round 1 candidates", "it", ""


def test_heartbeat_says_the_step_and_how_far_at_most_every_interval():
    now, lines = [100.0], []
    pulse = progress.Pulse("diagnose", lines.append, every=10, clock=lambda: now[0])
    now[0] = 104.0
    assert pulse.beat() is None
    now[0] = 110.0
    assert pulse.beat() == "diagnose: working (10 s)"  # before any step: loading, compiling
    bar = _Bar()
    now[0] = 112.0
    pulse.started(bar)
    for t in (113.0, 119.9):
        now[0] = t
        assert pulse.beat() is None  # 10 s after the last line, not after the bar's start
    now[0] = 120.0
    assert pulse.beat() == "diagnose: round 1 candidates, 3 of 12 (8 s)"
    now[0], bar.n, bar.postfix = 135.4, 4, "chi2 1.2"
    assert pulse.beat() == "diagnose: round 1 candidates, 4 of 12 (23 s), chi2 1.2"
    inner = _Bar()
    inner.total, inner.desc, inner.postfix = None, "emcee\x1b[2J", ""
    pulse.started(inner)
    assert pulse.line(140.0) == "diagnose: emcee\\x1b[2J, 3 it (5 s)"  # the innermost; no total; escaped
    pulse.finished(inner)
    pulse.finished(bar)
    assert pulse.line(150.0) == "diagnose: working (50 s), after round 1 candidates"
    assert lines == ["diagnose: working (10 s)", "diagnose: round 1 candidates, 3 of 12 (8 s)",
                     "diagnose: round 1 candidates, 4 of 12 (23 s), chi2 1.2"]


@pytest.mark.parametrize("value, every", [("", 10.0), ("30", 30.0), ("2.5", 2.5), ("off", None), ("0", None),
                                          ("-1", 10.0), ("soon", 10.0), ("nan", 10.0)])
def test_heartbeat_interval_from_the_environment(value, every):
    assert progress.heartbeat_every({progress.HEARTBEAT_ENV: value}) == every


def test_the_command_line_turns_the_heartbeat_on_without_a_terminal(monkeypatch):
    """Under ``main()`` a command has a heartbeat on a stderr that is not a terminal, and an
    auto bar reports its count to it (the fake clock decides the times); not under
    ``--quiet``, not for ``progress=False``, not in the library outside the command line."""
    from cstiffjax.commands import check, cli

    monkeypatch.delenv(progress.HEARTBEAT_ENV, raising=False)
    now, seen = [0.0], []
    monkeypatch.setattr(progress, "_clock", lambda: now[0])

    def fake_run(args):
        pulse = progress._state["heartbeat"]
        for _ in progress.bar(range(5), desc="sweep"):
            now[0] += 1.0
            seen.append(pulse and pulse.line(now[0]))
        seen.append(pulse and pulse.line(now[0]))
        seen.append(getattr(progress.bar(range(2), progress=False), "pulse", None))
        return 0

    monkeypatch.setattr(check, "run", fake_run)
    assert cli.main(["check", "tcpr8.toml"]) == 0
    assert seen[0] == "check: sweep, 0 of 5 (1 s)"  # the steps done: counted by the bar as it runs
    assert seen[4:] == ["check: sweep, 4 of 5 (5 s)", "check: working (5 s), after sweep", None]
    assert progress._state["heartbeat"] is None  # stopped when the command ends
    seen.clear()
    assert cli.main(["check", "tcpr8.toml", "--quiet"]) == 0
    assert seen == [None] * 6 + [None]
    assert getattr(progress.bar(range(2)), "pulse", None) is None  # the library alone: nothing
