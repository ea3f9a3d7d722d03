"""Nothing lost, nothing stale: a finished result is written before any check of it (a failed
check is reported, exit 3, never blamed on the inputs); parameters the recordings do not
determine are reported as such; outputs appear whole or not at all (Ctrl-C exits 130, a full
disk exits 4 with one line, ``kill -9`` leaves the previous output); no output through a hard
link to an input; text from the inputs cannot reach the terminal or the report as markup, nor
become a path."""

import ast
import errno
import functools
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import numpy as np
import pytest

import fitting.diagnosis.diagnose
from cstiffjax.cable.laws import CableLaw
from cstiffjax.commands.cli import main
from cstiffjax.core.status import to_codes
from cstiffjax.examples import example_path
from cstiffjax.io import atomic
from cstiffjax.io.recordings import load_recordings
from cstiffjax.io.robot_io import load_robot, save_robot
from cstiffjax.statics.forward import StaticsProblem, forward_statics
from cstiffjax.statics.geometry import cable_lengths
from fitting.synth.generate import Case, simulate, write_recordings

ROOT = Path(__file__).resolve().parent.parent
POSE = ["--pose", "0", "0", "0.83", "0", "0", "0"]


def _tree(folder: Path) -> dict:
    """``{relative path: bytes}`` of every file under ``folder`` (hidden ones included)."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture
def small_diagnose(monkeypatch):
    """The CLI's diagnosis restricted to the baseline (cheap); the command logic is unchanged."""
    monkeypatch.setattr(fitting.diagnosis.diagnose, "diagnose",
                        functools.partial(fitting.diagnosis.diagnose.diagnose, effects=(), posterior_steps=0))


@pytest.fixture(scope="module")
def small(lab):
    """The baseline-only diagnosis of ``lab`` (reused by the tests that only write it)."""
    robot = load_robot(lab[0])
    return fitting.diagnosis.diagnose.diagnose(robot, load_recordings(lab[1], robot), effects=(), posterior_steps=0)


# ------------------------------------------------------ 1. a finished result is never discarded
@pytest.fixture(scope="module")
def slack_cable(tmp_path_factory):
    """A TCPR-8 whose cable 5 is 20 % longer than its path at every pose: it carries no tension
    in any sample (recorded: load-cell noise about 0), so nothing determines its EA. The other
    seven cables hold the platform; poses and tensions are settled by forward statics."""
    robot, cols, _ = simulate(Case("slack", "tcpr8"), n=20, seed=1)
    l0 = np.stack([cols[f"l0_{i + 1}"] for i in range(8)], 1)
    ext = np.stack([cols[k] for k in ("fx", "fy", "fz", "mx", "my", "mz")], 1)
    pose0 = np.stack([cols[k] for k in ("x", "y", "z", "rx", "ry", "rz")], 1)
    length = np.array([np.asarray(cable_lengths(robot, p)) for p in pose0])
    l0[:, 4] = 1.2 * length[:, 4]
    def settle(l, e, p):
        return forward_statics(StaticsProblem(robot, l, e, CableLaw.spring), pose0=p, throw=False)

    fs = jax.vmap(settle)(l0, ext, pose0)
    pose, ten = np.asarray(fs.pose), np.asarray(fs.tensions)
    assert np.all(np.asarray(to_codes(fs.result)) == 0) and np.all(ten[:, 4] == 0) and np.all(np.delete(ten, 4, 1) > 5)
    rng = np.random.default_rng(0)  # with this noise the fit drives cable 5's EA to exactly 0 (exp underflows)
    pose = pose + rng.normal(0, 1e-6, pose.shape)  # tracker noise (1e-6 m, and as small in rad)
    ten = ten + rng.normal(0, float(robot.noise.tension), ten.shape)
    cols.update({f"l0_{i + 1}": l0[:, i] for i in range(8)})
    cols.update({k: pose[:, j] for j, k in enumerate(("x", "y", "z", "rx", "ry", "rz"))})
    cols.update({f"t_{i + 1}": ten[:, i] for i in range(8)})
    d = tmp_path_factory.mktemp("slack")
    save_robot(robot, d / "robot.toml")
    write_recordings(cols, d / "recordings.csv")
    return d / "robot.toml", d / "recordings.csv"


def test_unidentified_cable_keeps_the_result(slack_cable, tmp_path, capsys, small_diagnose):
    """The fit drives the slack cable's EA to (almost) 0; the diagnosis is still written (JSON,
    report, figures), the nominal EA is reported for that cable and flagged, exit 0."""
    out, rep = tmp_path / "d.json", tmp_path / "rep"
    code = main(["diagnose", *map(str, slack_cable), "--json", str(out), "--report", str(rep), "--quiet"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "diagnosis JSON" not in err
    doc = json.loads(out.read_text())
    nominal = float(load_robot(slack_cable[0]).EA[4])
    for stage in ("baseline", "final"):
        cal = doc[stage]["calibrated"]
        assert [u["cable"] for u in cal["unidentified"]] == [5], cal
        assert cal["EA"][4] == pytest.approx(nominal, rel=1e-12)  # the nominal value, flagged
        assert all(v > 0 for v in cal["EA"])
        fitted = cal["unidentified"][0]["fitted_EA"]
        assert fitted is None or fitted < 1e-3 * nominal  # what the fit made of it: (almost) nothing
        others = np.delete(np.asarray(cal["EA"]), 4)
        assert np.all(np.abs(others / nominal - 1) < 0.01)  # the seven loaded cables: EA found
    assert any(w.startswith("baseline.calibrated.EA: cable 5:") for w in doc["warnings"])
    assert "cable 5: the recordings do not determine EA" in err and "warning:" in err
    assert {"report.md", "diagnosis.json", "chi2_shares.png"} <= {p.name for p in rep.iterdir()}
    assert "**Warnings**" in (rep / "report.md").read_text()
    assert json.loads((rep / "diagnosis.json").read_text()) == doc


def test_a_failed_self_check_still_writes_everything(small, lab, tmp_path, capsys, monkeypatch):
    """A result that fails the program's own §3 check is written all the same; the check is
    reported (stderr, `warnings`), naming the key, as a fault of the diagnosis; exit 3."""
    zero = {"EA": [0.0, *small.baseline["calibrated"]["EA"][1:]], "unidentified": []}  # as the old fit made it
    broken = fitting.diagnosis.diagnose.Diagnosis(**{**small.__dict__, "baseline": {**small.baseline,
                                                                                   "calibrated": zero}})
    monkeypatch.setattr(fitting.diagnosis.diagnose, "diagnose", lambda *a, **k: broken)
    out, rep = tmp_path / "d.json", tmp_path / "rep"
    assert main(["diagnose", *map(str, lab), "--json", str(out), "--report", str(rep), "--quiet"]) == 3
    captured = capsys.readouterr()
    err = captured.err
    assert "'baseline.calibrated.EA': must be a list of positive numbers" in err
    assert "not of the robot or the recordings" in err and "error:" not in err and "diagnosis JSON" not in err
    assert "explained: true" in captured.out  # the verdict line is printed as usual
    doc = json.loads(out.read_text())
    assert doc["baseline"]["calibrated"]["EA"][0] == 0.0  # written as computed
    assert any("baseline.calibrated.EA" in w for w in doc["warnings"])
    assert (rep / "report.md").exists() and json.loads((rep / "diagnosis.json").read_text()) == doc


def test_a_figure_that_cannot_be_drawn_leaves_the_report(small, lab, tmp_path, capsys, monkeypatch):
    """A figure that fails is left out and named (stderr, warnings, the report); exit 3."""
    import fitting.diagnosis.report_figures as report_figures

    def fail(*a, **k):
        raise ValueError("no axes today")

    monkeypatch.setattr(fitting.diagnosis.diagnose, "diagnose", lambda *a, **k: small)
    monkeypatch.setattr(report_figures, "_chi2_plan", fail)
    rep = tmp_path / "rep"
    assert main(["diagnose", *map(str, lab), "--report", str(rep), "--quiet"]) == 3
    assert "chi2_shares.png: not written (ValueError: no axes today)" in capsys.readouterr().err
    assert {p.name for p in rep.iterdir()} == {"report.md", "diagnosis.json", "robot.png"} | (
        {"residuals.png"} if (rep / "residuals.png").exists() else set())
    assert "chi2_shares.png: not written" in json.loads((rep / "diagnosis.json").read_text())["warnings"][-1]


# ----------------------------------------------------------------------- 2. atomic outputs
class _FullDisk:
    """An ``open`` whose files take half of what is written, then fail with ENOSPC."""

    def __init__(self):
        self.real = open

    def __call__(self, path, mode="r", *a, **k):
        fh = self.real(path, mode, *a, **k)
        if "r" in mode:
            return fh
        real_write = fh.write

        def write(data):
            real_write(data[: len(data) // 2])
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

        fh.write = write
        return fh


def test_a_full_disk_leaves_the_previous_file_and_one_line(tmp_path, capsys, monkeypatch):
    out = tmp_path / "k.json"
    assert main(["stiffness", "tcpr8.toml", *POSE, "--json", str(out)]) == 0
    before = out.read_bytes()
    capsys.readouterr()
    monkeypatch.setattr(atomic, "open", _FullDisk(), raising=False)
    assert main(["stiffness", "tcpr8.toml", *POSE, "--json", str(out)]) == 4
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert "No space left on device" in err and "k.json" in err
    assert out.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["k.json"]


def test_ctrl_c_exits_130_and_keeps_the_previous_report(small, lab, tmp_path, capsys, monkeypatch):
    import fitting.diagnosis.report_figures as report_figures

    monkeypatch.setattr(fitting.diagnosis.diagnose, "diagnose", lambda *a, **k: small)
    rep = tmp_path / "rep"
    assert main(["diagnose", *map(str, lab), "--report", str(rep), "--quiet"]) == 0
    before = _tree(rep)

    def interrupt(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(report_figures, "_chi2_plan", interrupt)  # Ctrl-C half-way through the new report
    capsys.readouterr()
    assert main(["diagnose", *map(str, lab), "--report", str(rep), "--quiet"]) == 130
    err = capsys.readouterr().err
    lines = err.splitlines()  # the earlier report announced, then the interruption; nothing else
    assert len(lines) == 2 and lines[0].startswith("note: replacing") and "interrupted" in lines[1]
    assert "Traceback" not in err
    assert _tree(rep) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rep"]  # no temporary folder left


def test_a_new_report_replaces_the_old_one_whole(small, tmp_path):
    """The previous report's figures that the new one does not draw are gone (nothing stale);
    in a folder that also holds other files these stay and only the report's own files change."""
    import fitting.diagnosis.report as report

    rep = tmp_path / "rep"
    rep.mkdir()
    (rep / "discovered_1.png").write_bytes(b"old figure")
    (rep / "report.md").write_text("old report")
    report.write_report(small, rep)
    assert "discovered_1.png" not in {p.name for p in rep.iterdir()}
    assert (rep / "report.md").read_text().startswith("# Mismatch diagnosis")
    (rep / "discovered_2.png").write_bytes(b"old figure")
    (rep / "notes.txt").write_text("mine")  # not an output of the report: the folder is updated in place
    report.write_report(small, rep)
    names = {p.name for p in rep.iterdir()}
    assert "notes.txt" in names and (rep / "notes.txt").read_text() == "mine" and "discovered_2.png" not in names
    assert not [n for n in names if n.startswith(".")]


def test_kill_9_leaves_the_previous_folder(tmp_path):
    """A process killed (SIGKILL) while it writes a folder output leaves the previous one intact."""
    out = tmp_path / "out"
    with atomic.output_folder(out, ("a.txt", "b.txt")) as tmp:
        (tmp / "a.txt").write_text("old a")
        (tmp / "b.txt").write_text("old b")
    before = _tree(out)
    code = textwrap.dedent(f"""
        import sys, time
        from cstiffjax.io import atomic
        with atomic.output_folder({str(out)!r}, ("a.txt", "b.txt")) as tmp:
            (tmp / "a.txt").write_text("new a")
            (tmp / "b.txt").write_text("new b, half")
            print("written", flush=True)
            time.sleep(60)
    """)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, env=env)
    try:
        assert proc.stdout.readline().strip() == "written"
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        proc.kill()
    assert _tree(out) == before
    with atomic.output_folder(out, ("a.txt", "b.txt")) as tmp:  # the next run replaces it whole
        (tmp / "a.txt").write_text("new a")
    assert _tree(out) == {"a.txt": b"new a"}


def test_write_text_keeps_the_old_file_on_an_error(tmp_path, monkeypatch):
    path = tmp_path / "x.json"
    atomic.write_text(path, "old")
    monkeypatch.setattr(atomic, "open", _FullDisk(), raising=False)
    with pytest.raises(OSError, match="No space"):
        atomic.write_text(path, "new and longer")
    assert path.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["x.json"]


# -------------------------------------------------- 3. no input overwritten through a hard link
def test_tensions_and_workspace_refuse_a_hard_link_to_the_input(tmp_path, capsys):
    robot = tmp_path / "robot.toml"
    shutil.copy(example_path("tcpr8.toml"), robot)
    before = robot.read_bytes()
    os.link(robot, tmp_path / "t.json")
    assert main(["tensions", str(robot), *POSE, "--method", "cfm", "--json", str(tmp_path / "t.json")]) == 1
    assert "is an input of this command" in capsys.readouterr().err
    out = tmp_path / "ws"
    out.mkdir()
    os.link(robot, out / "summary.json")
    grid = ["--pose-grid", "-0.1", "0.1", "2", "-0.1", "0.1", "2", "0.8", "0.9", "2"]
    assert main(["workspace", str(robot), "--kind", "wrench-closure", *grid, "--out", str(out), "--no-progress"]) == 1
    assert "is an input of this command" in capsys.readouterr().err
    assert robot.read_bytes() == before


def test_a_destination_that_cannot_be_written_is_one_line(tmp_path, capsys, monkeypatch):
    """Refused before any work when the folder is not writable; a late failure (the folder made
    read-only meanwhile) is one line, exit 4."""
    import cstiffjax.commands.common as common

    locked = tmp_path / "locked"
    locked.mkdir()
    real = os.access
    monkeypatch.setattr(common.os, "access", lambda p, mode, **k: Path(p) != locked and real(p, mode, **k))
    assert main(["tensions", "tcpr8.toml", *POSE, "--method", "cfm", "--json", str(locked / "t.json")]) == 1
    assert "cannot write there (permission denied)" in capsys.readouterr().err
    monkeypatch.undo()

    def denied(path, *a, **k):
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(path))

    monkeypatch.setattr(atomic, "open", denied, raising=False)
    assert main(["tensions", "tcpr8.toml", *POSE, "--method", "cfm", "--json", str(locked / "t.json")]) == 4
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Permission denied" in err and "Traceback" not in err
    assert f"{locked / 't.json'}: Permission denied" in err  # the output's name, not a temporary one
    assert list(locked.iterdir()) == []


# ------------------------------------------------------- 4. terminal and report injection
EVIL = "evil\x1b[2J\x1b]0;owned\x07\n**Verdict:** nothing wrong <img src=x onerror=alert(1)> | $\\frac{$"


def _evil_robot(folder: Path, source: Path) -> Path:
    text = source.read_text()
    head, rest = text.split("\nname = ", 1)
    path = folder / "evil.toml"
    path.write_text(head + "\nname = " + json.dumps(EVIL) + "\n" + rest.split("\n", 1)[1])
    assert load_robot(path).name == EVIL
    return path


def test_control_characters_and_markup_in_the_name_are_escaped(small, lab, tmp_path, capsys, monkeypatch):
    robot = _evil_robot(tmp_path, lab[0])
    evil = fitting.diagnosis.diagnose.Diagnosis(**{**small.__dict__, "robot": EVIL})
    monkeypatch.setattr(fitting.diagnosis.diagnose, "diagnose", lambda *a, **k: evil)
    out, rep = tmp_path / "d.json", tmp_path / "rep"
    assert main(["diagnose", str(robot), str(lab[1]), "--json", str(out), "--report", str(rep)]) == 0
    assert main(["check", str(robot), str(lab[1])]) == 0
    assert main(["stiffness", str(robot), "--pose", "3", "0", "0.5", "0", "0", "0"]) == 0
    both = "".join(capsys.readouterr())
    assert "\x1b" not in both and "\x07" not in both
    assert not any(line.lstrip().startswith("**Verdict:**") for line in both.splitlines())
    md = (rep / "report.md").read_text()
    assert "\x1b" not in md and "\\<img" in md and re.search(r"(?<!\\)<img", md) is None  # no raw tag
    verdicts = [line for line in md.splitlines() if line.startswith("**Verdict:**")]  # a forged one would start so
    assert len(verdicts) == 1 and "nothing wrong" not in verdicts[0]
    assert md.splitlines()[0].startswith(r"# Mismatch diagnosis: evil\\x1b\[2J")  # renders as evil\x1b[2J
    assert json.loads(out.read_text())["robot"] == EVIL  # the JSON keeps the name as it is
    assert (rep / "chi2_shares.png").exists()  # `$...$` in the title did not stop the figure


# ------------------------------------------------------------ 5. no input used as a path
def test_names_never_become_paths(lab, tmp_path, monkeypatch, capsys, small_diagnose):
    """A robot named ``../../x`` and covariates named like paths write nothing outside the
    chosen output folder (the working folder is inside the watched tree)."""
    work = tmp_path / "a" / "b"
    work.mkdir(parents=True)
    text = lab[0].read_text()
    head, rest = text.split("\nname = ", 1)
    (work / "robot.toml").write_text(head + '\nname = "../../x"\n' + rest.split("\n", 1)[1])
    lines = lab[1].read_text().splitlines()
    absolute = tmp_path / "abs"
    lines = [lines[0] + f",../../cov,{absolute}"] + [f"{r},{k % 7},{k % 3}" for k, r in enumerate(lines[1:])]
    (work / "rec.csv").write_text("\n".join(lines) + "\n")
    monkeypatch.chdir(work)
    before = set(tmp_path.rglob("*"))
    assert main(["diagnose", "robot.toml", "rec.csv", "--report", "out", "--json", "out.json", "--quiet"]) == 0
    assert main(["fit", "robot.toml", "rec.csv", "--plots", "plots"]) == 0
    made = set(tmp_path.rglob("*")) - before
    allowed = [work / "out", work / "out.json", work / "plots"]
    assert made and [p for p in made if not any(p == a or a in p.parents for a in allowed)] == []


def _runs_text(source: str, where: str) -> list[str]:
    """Calls of ``eval``/``exec``, ``os.system``/``os.popen``/``os.exec*``/``os.spawn*`` and
    imports of ``subprocess``/``pty`` in ``source`` (AST based), as ``where:line: what``."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import | ast.ImportFrom):
            names = [a.name for a in node.names] + ([node.module] if isinstance(node, ast.ImportFrom) else [])
            if any(n and n.split(".")[0] in ("subprocess", "pty") for n in names):
                found.append(f"{where}:{node.lineno}: imports {names}")
        if isinstance(node, ast.Call):
            f = node.func
            name = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else ""
            owner = f.value.id if isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name) else None
            if (owner is None and name in ("eval", "exec")) or (
                    owner == "os" and (name in ("system", "popen") or name.startswith(("exec", "spawn")))):
                found.append(f"{where}:{node.lineno}: calls {owner + '.' if owner else ''}{name}")
    return found


def test_no_module_runs_a_shell_or_evaluates_text():
    """No module of the packages evaluates text or starts a program: text from the inputs has
    no way to run. (The checker finds each kind of call planted in a snippet.)"""
    planted = "import subprocess\nimport os\neval(x)\nos.system(name)\nos.execv(p, a)\n"
    assert len(_runs_text(planted, "planted")) == 4
    found = []
    for path in [*ROOT.glob("cstiffjax/**/*.py"), *ROOT.glob("fitting/**/*.py")]:
        found += _runs_text(path.read_text(), str(path.relative_to(ROOT)))
    # the two exceptions, each this Python with a fixed argv and no shell, the data as pickles on
    # its stdin: the report's figure process (a file of the package) and the IRMA4U reader's child
    # (a constant program of the module, so that a damaged .mat that crashes scipy's reader ends
    # the child, not the command)
    worker = ROOT / "fitting" / "diagnosis" / "figure_worker.py"
    assert [f.split(": ", 1)[1] for f in found] == ["imports ['subprocess']"] * 2
    assert sorted(f.split(":", 1)[0] for f in found) == ["cstiffjax/io/irma4u.py", "fitting/diagnosis/figure_worker.py"]
    irma = ast.parse((ROOT / "cstiffjax" / "io" / "irma4u.py").read_text())
    runs = [n for n in ast.walk(irma) if isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute)
            and n.func.attr in ("run", "Popen", "call", "check_output") and ast.unparse(n.func.value) == "subprocess"]
    assert len(runs) == 1 and ast.unparse(runs[0].args[0]) == "[sys.executable, '-c', _CHILD]"
    assert all(k.arg != "shell" for k in runs[0].keywords)
    assert any(isinstance(n, ast.Assign) and [ast.unparse(t) for t in n.targets] == ["_CHILD"]
               and isinstance(n.value, ast.Constant) for n in irma.body)  # a constant program, never built from input
    popens = [n for n in ast.walk(ast.parse(worker.read_text())) if isinstance(n, ast.Call)
              and isinstance(n.func, ast.Attribute) and n.func.attr == "Popen"]
    assert len(popens) == 1 and ast.unparse(popens[0].args[0]) == "[sys.executable, str(Path(__file__).resolve())]"
    assert all(k.arg != "shell" for k in popens[0].keywords)
