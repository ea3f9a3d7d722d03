"""The pictures: the robot's cables where the physics puts them, colour scales that say
something, sections where the user asked. Checked on the drawn data, not on pixels."""

from pathlib import Path

import numpy as np
import pytest

from cstiffjax.cable.path import robot_paths
from cstiffjax.examples import example_path
from cstiffjax.io.robot_io import load_robot
from cstiffjax.plots.robot import cable_shapes, plot_robot
from cstiffjax.plots.workspace import colour_range, plot_members_3d, plot_sections, section_indices
from cstiffjax.statics.geometry import frame
from cstiffjax.statics.sag import sagging_inverse_statics


def _attachments(robot, pose):
    p, R = (np.asarray(v) for v in frame(pose))
    return p + np.asarray(robot.attachments) @ R.T


def test_straight_cables_run_from_anchor_to_attachment():
    robot = load_robot(example_path("tcpr8.toml"))
    pose = np.array([0.0, 0.0, 0.83, 0.0, 0.0, 0.0])
    att = _attachments(robot, pose)
    for i, shape in enumerate(cable_shapes(robot, pose)):
        np.testing.assert_allclose(shape[0], robot.anchors[i], atol=1e-12)
        np.testing.assert_allclose(shape[-1], att[i], atol=1e-12)
        d = np.diff(shape[1:], axis=0)  # the free span: collinear points
        assert np.allclose(np.cross(d[0], d[1:]), 0.0, atol=1e-12)


def test_heavy_cables_hang_below_their_chord_and_meet_their_ends():
    """prototype_8mm (8 mm steel cables over 4-7 m): with the lengths of the sagging inverse
    statics each cable's catenary ends at its attachment (to the solver's tolerance) and
    its middle hangs below the chord by about ``w L² / (8 H)``."""
    robot = load_robot(example_path("prototype_8mm.toml"))
    pose = np.array([0.0, 0.0, 0.5, 0.0, 0.0, 0.0])
    inv = sagging_inverse_statics(robot, pose)
    att = _attachments(robot, pose)
    shapes = cable_shapes(robot, pose, np.asarray(inv.l0), points=41)
    g = float(np.linalg.norm(robot.gravity))
    for i, shape in enumerate(shapes):
        np.testing.assert_allclose(shape[-1], att[i], atol=1e-6)
        a, b, mid = shape[1], shape[-1], shape[1 + 20]
        chord_mid = 0.5 * (a + b)
        sag = chord_mid[2] - mid[2]
        w, t = float(robot.mass_per_length[i]) * g, float(inv.tensions[i])
        horizontal = np.hypot(*(b - a)[:2])
        assert sag > 0
        np.testing.assert_allclose(sag, w * horizontal**2 / (8 * t), rtol=0.25)  # the parabola's mid-span sag


def test_cables_over_pulleys_wrap_then_leave_at_the_tangent_point():
    robot = load_robot(example_path("pulleys8/robot.toml"))
    pose = np.array([0.0, 0.0, 0.6, 0.0, 0.0, 0.0])
    att = _attachments(robot, pose)
    paths = robot_paths(robot, att)
    for i, shape in enumerate(cable_shapes(robot, pose)):
        k = int(np.argmin(np.linalg.norm(shape - np.asarray(paths.tangent_point[i]), axis=1)))
        arc = shape[:k + 1]
        np.testing.assert_allclose(arc[0], robot.anchors[i], atol=1e-12)
        r = np.linalg.norm(arc - np.asarray(paths.centre[i]), axis=1)
        np.testing.assert_allclose(r, float(robot.pulley_radius[i]), rtol=1e-9)
        np.testing.assert_allclose(shape[-1], att[i], atol=1e-12)


def test_plot_robot_writes_a_picture_with_arrows_scaled_to_the_frame(tmp_path):
    robot = load_robot(example_path("pulleys8/robot.toml"))
    out = plot_robot(robot, [0, 0, 0.6, 0, 0, 0], tmp_path / "robot.png", highlight=(2,),
                     arrows=np.full((8, 3), 1e-3), arrow_label="anchor offsets")
    assert out.stat().st_size > 10_000


def test_a_constant_colour_scale_is_named_not_drawn():
    member = np.ones((3, 3, 3), bool)
    lo, hi, constant = colour_range(np.full((3, 3, 3), 0.085), member)
    assert constant == pytest.approx(0.085) and lo < 0.085 < hi
    assert colour_range(np.arange(27.0).reshape(3, 3, 3), member) == (0.0, 26.0, None)


def test_sections_at_the_requested_heights():
    z = np.linspace(0.5, 1.5, 11)
    assert section_indices(z, at=[0.83]).tolist() == [3]
    assert section_indices(z, count=3).tolist() == [0, 5, 10]


def test_workspace_figures_with_the_robot_and_a_constant_margin(tmp_path):
    robot = load_robot(example_path("tcpr8.toml"))
    axes = [np.linspace(-0.2, 0.2, 5), np.linspace(-0.2, 0.2, 5), np.linspace(0.6, 1.0, 5)]
    member = np.zeros((5, 5, 5), bool)
    member[1:4, 1:4, 1:4] = True
    margin = np.full((5, 5, 5), 0.085)
    assert plot_members_3d(axes, member, margin, tmp_path / "a.png", "t", "margin [m]", robot=robot).exists()
    assert plot_sections(axes, member, margin, tmp_path / "b.png", "t", "margin [m]", at=[0.8]).exists()


# ------------------------------------------------------------------ the diagnosis' pictures
@pytest.fixture(scope="module")
def diagnosis():
    """A baseline-only diagnosis of the bundled pulleys8 recordings (no effect searched)."""
    import fitting
    from cstiffjax.io.recordings import load_recordings

    robot = load_robot(example_path("pulleys8/robot.toml"))
    rec = load_recordings(example_path("pulleys8/recordings.csv"), robot)
    return fitting.diagnose(robot, rec, effects=(), posterior_steps=0)


def test_diagnosis_summary_report_and_figures(diagnosis, tmp_path):
    text = diagnosis.summary()
    assert text.splitlines()[0].startswith("baseline  chi2/dof") and "explained" in text
    report = diagnosis.write_report(tmp_path / "rep")
    names = sorted(p.name for p in report.parent.iterdir())
    assert {"report.md", "diagnosis.json", "chi2_shares.png", "robot.png"} <= set(names)
    assert "![robot.png](robot.png)" in report.read_text()
    figures = diagnosis.plot()
    assert {"chi2_shares.png", "robot.png"} <= set(figures)
    import matplotlib.pyplot as plt

    for fig in figures.values():
        assert fig.axes
        plt.close(fig)


def _pngs(folder):
    return {p.name: p.read_bytes() for p in Path(folder).glob("*.png")}


def test_the_figure_process_draws_the_reports_figures(diagnosis, tmp_path, monkeypatch):
    """:class:`FigureWorker` draws in a child process what ``write_report`` draws here: the
    same files byte for byte and the same report; the report does not draw them again
    (``write_figures`` would fail); the child's temporary folder is gone after the block."""
    import fitting.diagnosis.report as report
    from fitting.diagnosis.figure_worker import FigureWorker

    write_report = report.write_report
    write_report(diagnosis, tmp_path / "here")
    with monkeypatch.context() as m:
        m.setattr(report, "write_figures", lambda *a, **k: pytest.fail("the figures were drawn twice"))
        with FigureWorker() as worker:
            worker.start()
            worker.submit(diagnosis)
            problems = []
            write_report(diagnosis, tmp_path / "child", problems=problems, figures=worker)
            folder = worker._folder.name
    assert not Path(folder).exists() and problems == []
    here = _pngs(tmp_path / "here")
    assert set(here) >= {"chi2_shares.png", "robot.png"} and _pngs(tmp_path / "child") == here
    assert (tmp_path / "child" / "report.md").read_text() == (tmp_path / "here" / "report.md").read_text()


def test_the_figure_process_never_imports_jax(diagnosis, tmp_path):
    """The child (the module run as a script) draws every plan without importing JAX (it
    would add a second to its start) and answers with the files and problems as JSON."""
    import json
    import pickle
    import subprocess
    import sys

    import fitting.diagnosis.figure_worker as figure_worker
    from fitting.diagnosis.report_figures import figure_plans

    plans = figure_plans(diagnosis)
    job = pickle.dumps({"folder": str(tmp_path), "plans": plans})
    out = subprocess.run([sys.executable, figure_worker.__file__], input=job, capture_output=True, check=True)
    answer = json.loads(out.stdout)
    assert answer == {"files": [name for name, _, _ in plans], "problems": [], "jax": False}
    assert sorted(_pngs(tmp_path)) == sorted(answer["files"])


def test_the_figure_process_on_a_full_disk_exits_1_without_a_traceback(diagnosis, tmp_path):
    """No byte can be written (``RLIMIT_FSIZE`` 0, set in a launcher that then runs the child):
    the child ends with exit 1 and nothing on stderr (the report then draws the figures
    itself, and the command names the error in one line)."""
    import pickle
    import subprocess
    import sys

    import fitting.diagnosis.figure_worker as figure_worker
    from fitting.diagnosis.report_figures import figure_plans

    launch = ("import os, resource, sys; resource.setrlimit(resource.RLIMIT_FSIZE, (0, 0)); "
              "os.execv(sys.executable, [sys.executable, sys.argv[1]])")
    job = pickle.dumps({"folder": str(tmp_path), "plans": figure_plans(diagnosis)})
    out = subprocess.run([sys.executable, "-c", launch, figure_worker.__file__], input=job, capture_output=True,
                         timeout=300)
    assert out.returncode == 1 and out.stderr == b"" and out.stdout == b"", out.stderr[-2000:]


def _no_axes(diagnosis):
    raise ValueError("no axes today")


@pytest.mark.parametrize("plan, error", [
    (lambda d: {"title": "no bars"}, "KeyError: 'ticks'"),  # drawn by the child: it fails there
    (_no_axes, "ValueError: no axes today"),  # fails here, before the child sees it
], ids=["cannot_draw", "plan_fails"])
def test_a_figure_that_fails_is_named_once_and_the_rest_drawn_by_the_process(diagnosis, tmp_path, monkeypatch,
                                                                              plan, error):
    """A plan the child cannot draw, or one that cannot be computed here, is a problem named
    once, as ``best_effort`` names it (the report's warnings); the other figures are drawn;
    no file is left for the failed one."""
    import json

    import fitting.diagnosis.report_figures as report_figures
    from fitting.diagnosis.figure_worker import FigureWorker
    from fitting.diagnosis.report import write_report

    monkeypatch.setattr(report_figures, "_chi2_plan", plan)
    problems = []
    with FigureWorker() as worker:
        worker.submit(diagnosis)
        write_report(diagnosis, tmp_path / "rep", problems=problems, figures=worker)
    assert problems == [f"chi2_shares.png: not written ({error})"]
    assert "chi2_shares.png" not in _pngs(tmp_path / "rep") and "robot.png" in _pngs(tmp_path / "rep")
    doc = json.loads((tmp_path / "rep" / "diagnosis.json").read_text())
    assert doc["warnings"][-1] == f"report figure chi2_shares.png: not written ({error})"


@pytest.mark.parametrize("child", ["sys.exit(2)", "time.sleep(60)"], ids=["dies", "hangs"])
def test_a_figure_process_that_fails_leaves_the_figures_to_the_report(diagnosis, tmp_path, monkeypatch, child):
    """A child that fails (exits 2 without an answer; hangs past ``TIMEOUT_S``, then it is
    killed) costs nothing but its time: the report draws the figures itself, the same files
    as always."""
    import subprocess
    import sys
    import time

    import fitting.diagnosis.figure_worker as figure_worker
    from fitting.diagnosis.report import write_report

    monkeypatch.setattr(figure_worker, "TIMEOUT_S", 1.0)
    write_report(diagnosis, tmp_path / "here")
    start = time.perf_counter()
    with figure_worker.FigureWorker() as worker:
        worker._proc = subprocess.Popen([sys.executable, "-c", f"import sys, time; sys.stdin.buffer.read(); {child}"],
                                        stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        worker.submit(diagnosis)
        assert worker.submitted
        write_report(diagnosis, tmp_path / "rep", figures=worker)
    assert _pngs(tmp_path / "rep") == _pngs(tmp_path / "here") and time.perf_counter() - start < 30


def test_the_robot_view_highlights_the_cable_with_the_largest_misfit(diagnosis):
    from fitting.diagnosis.report import robot_view

    pose, highlight, arrows, _ = robot_view(diagnosis)
    a = diagnosis.arrays
    chi2 = np.sum(a["r_base"][a["keep"], 6:] ** 2, 0)
    assert highlight[0] == int(np.argmax(chi2)) and arrows is None
    assert any(np.array_equal(pose, p) for p in a["poses"])


# ------------------------------------------------------------------ fit figures
@pytest.fixture(scope="module")
def pulley_fit():
    import fitting
    from cstiffjax.io.recordings import load_recordings

    robot = load_robot(example_path("pulleys8/robot.toml"))
    rec = load_recordings(example_path("pulleys8/recordings.csv"), robot)
    return fitting.calibrate(robot, rec, free=("EA", "length_offset"))


def test_residual_plot_one_panel_per_channel_group_distinct_colours(pulley_fit):
    import matplotlib.pyplot as plt

    from fitting.plots import residual_plot

    fig = residual_plot(pulley_fit)
    titles = [ax.get_ylabel().split("\n")[0] for ax in fig.axes]
    assert titles == ["position", "orientation", "tension"]
    for ax in fig.axes:
        colours = [tuple(line.get_color()) if not isinstance(line.get_color(), str) else line.get_color()
                   for line in ax.get_lines()]
        assert len(colours) == len(set(colours))
    assert len(fig.axes[2].get_lines()) == 8
    plt.close(fig)


def test_corner_labels_carry_units_and_few_ticks(pulley_fit):
    import types

    import matplotlib.pyplot as plt

    from fitting.plots import corner

    names = list(pulley_fit.names)[:3]
    rng = np.random.default_rng(0)
    samples = rng.normal(size=(500, 3)) * 1e-3 + 1.0
    post = types.SimpleNamespace(names=names, fit=pulley_fit, flat=lambda: samples)
    fig = corner(post)
    labels = [ax.get_xlabel() for ax in fig.axes if ax.get_visible() and ax.get_xlabel()]
    assert labels[0].startswith("EA") and labels[0].endswith("[N]")
    assert all(len(ax.get_xticks()) <= 5 for ax in fig.axes if ax.get_visible())
    plt.close(fig)


def test_the_report_residual_panels_have_their_own_scales(diagnosis, tmp_path):
    import matplotlib.pyplot as plt

    from fitting.diagnosis.figure_render import render
    from fitting.diagnosis.report_figures import _localizer, _residual_plan

    j, cov = _localizer(diagnosis)
    if j is None:
        j, cov = 6, next(iter(diagnosis.arrays["covariates"]))
    fig = render("residuals", _residual_plan(diagnosis, j, cov), None)
    a, b = fig.axes[:2]
    assert a.get_shared_y_axes().get_siblings(a) == [a] and b.get_shared_y_axes().get_siblings(b) == [b]
    plt.close(fig)


def test_no_module_or_notebook_forces_a_matplotlib_backend():
    """A notebook's inline figures work: no package module and no notebook switches the
    backend (the command line sets ``MPLBACKEND=Agg`` for its own process only)."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    files = [*root.glob("cstiffjax/**/*.py"), *root.glob("fitting/**/*.py"), *root.glob("notebooks/*.ipynb")]
    assert files
    hits = [str(p.relative_to(root)) for p in files if "matplotlib.use(" in p.read_text()]
    assert hits == []


def test_check_plot_draws_the_robot(tmp_path, capsys):
    from cstiffjax.commands.cli import main

    out = tmp_path / "robot.png"
    assert main(["check", "pulleys8/robot.toml", "pulleys8/recordings.csv", "--plot", str(out)]) == 0
    assert out.stat().st_size > 10_000 and f"wrote {out}" in capsys.readouterr().out
    assert main(["check", "csjm.toml", "--plot", str(tmp_path / "csjm.png")]) == 1
    assert "--plot draws cable-driven parallel robots" in capsys.readouterr().err
    assert not (tmp_path / "csjm.png").exists()


# ------------------------------------------------------------------ report text and figure contents
def _cells(line: str) -> int:
    """Cells of a Markdown table line: ``|`` not escaped by a backslash separate them."""
    import re

    return len(re.split(r"(?<!\\)\|", line.strip())) - 2


def test_report_tables_hold_their_cells_and_say_what_each_name_means(diagnosis):
    """Grammar terms with ``|`` in their names stay in their cells; every internal name (a
    term, ``cov:k``, ``dir_i``, ``sag_i``) gets its words; the second round's candidates are
    listed; a closing section says what to check for the selected effect and what remains."""
    import dataclasses

    from fitting.diagnosis.report import markdown
    from fitting.diagnosis.selection import Candidate

    def cand(effect, dbic, reason):
        return Candidate(effect, dbic, 1.5, {}, 1, 10.0, 3.0, True, 0.2, reason=reason)

    tried2 = [{"effect": "term:l0|linear|cov:1|shared", "delta_bic": -40.0, "chi2_per_dof": 1.4, "accepted": False,
               "reason": "removes only 20% of the excess χ²"},
              {"effect": "term:tension|cgain|own_l0|per_cable", "delta_bic": -12.0, "chi2_per_dof": 1.45,
               "accepted": False, "reason": "Wald test fails"}]
    loc = {**diagnosis.localization, "channels": [
        {"where": "tension t_4", "share_of_chi2": 0.5, "correlates_with": "dir_4", "r": -0.9, "lag1": 0.1},
        {"where": "tension t_2", "share_of_chi2": 0.2, "correlates_with": "sag_2", "r": 0.4, "lag1": 0.0}],
           "own_readings": [{"r": 0.8, "not_drivers": ["t_4", "sag_4", "t_set_4"]}, {"r": 0.1, "not_drivers": []}]}
    d = dataclasses.replace(
        diagnosis, localization=loc, effects=["tension_sensor_bias"], explained=False,
        candidates=[cand("tension_sensor_bias", -90.0, "selected"),
                    cand("term:wrench[1]|offset|-|shared", -50.0, "removes only 39% of the excess χ²")],
        iterations=[{"round": 1, "model": [], "chi2_per_dof": 3.0, "tried": [], "added": "tension_sensor_bias"},
                    {"round": 2, "model": ["tension_sensor_bias"], "chi2_per_dof": 1.5, "tried": tried2,
                     "added": None}],
        final={**diagnosis.final, "parameters": {}, "residual_localization": loc["channels"][:1]},
        covariate_names=("humidity", "temperature"))
    text = markdown(d)
    for block in text.split("\n\n"):
        rows = [ln for ln in block.splitlines() if ln.startswith("|")]
        assert len({_cells(ln) for ln in rows}) <= 1, block  # every row of a table has the header's cells
    assert "| `term:wrench[1]\\|offset\\|-\\|shared` | a constant offset of the external force fy" in text
    assert "dir\\_4 (the direction of cable 4's last length change (+1 paid out, -1 hauled in))" in text
    assert "sag\\_2 (the sag parameter of cable 2, g·l0\\_2/t\\_2 (m/kg))" in text
    assert "an error linear in the covariate temperature of the commanded cable lengths, one for all cables" in text
    assert "`term:tension\\|cgain\\|own\\_l0\\|per\\_cable`" not in text  # a code span escapes only |
    assert "`term:tension\\|cgain\\|own_l0\\|per_cable` | a gain that changes with each cable's own commanded " \
           "length of the load-cell readings, one per cable" in text
    assert "Round 2 (model: baseline + tension\\_sensor\\_bias" in text and "Wald test fails" in text
    assert "tension t\\_4: the misfit follows its own reading (r 0.80)" in text
    _, _, tail = text.partition("## What to check next")
    assert tail and "re-zero the load cells with the cables unloaded" in tail
    assert "still unexplained: tension t\\_4 carries 50% of the remaining χ² and follows dir\\_4" in tail


def test_dimensionless_values_carry_no_unit():
    from fitting.diagnosis.report import _fmt_param, _value, unit_suffix

    gain = {"value": [1.042, 0.9977], "std": [0.0021, 0.0018], "unit": "1"}
    assert _fmt_param(gain) == "[1] 1.042 ± 0.0021<br>[2] 0.9977 ± 0.0018"
    assert _value(gain) == "2 values, largest |1.042| ± 0.0021"
    assert _value({"value": 3.5, "std": 0.1, "unit": "N"}) == "3.5 ± 0.1 N"
    assert [unit_suffix(u) for u in ("1", "", None, "m/kg")] == ["", "", "", " m/kg"]


def test_figures_draw_recorded_channels_only_and_tell_sessions_apart(diagnosis):
    """Channels without a recorded value get no bar or tick in ``chi2_shares``; with two
    sessions the residual panels draw each with its own label (the file's ids)."""
    import dataclasses

    import matplotlib.pyplot as plt

    from fitting.diagnosis.figure_render import render
    from fitting.diagnosis.report_figures import _chi2_plan, _residual_plan

    a = dict(diagnosis.arrays)
    a["r_base"], a["r_final"] = np.array(a["r_base"]), np.array(a["r_final"])
    a["r_base"][:, :3] = a["r_final"][:, :3] = 0.0  # x y z not recorded
    n = a["r_base"].shape[0]
    a["session"] = np.where(np.arange(n) < n // 2, 7, -3)
    d = dataclasses.replace(diagnosis, arrays=a)
    plan = _chi2_plan(d)
    m = a["robot"].num_cables
    assert plan["ticks"] == ["rx", "ry", "rz", *(f"t_{i + 1}" for i in range(m))]
    assert "position" not in plan["xlabel"] and plan["xlabel"].startswith("channel (orientation, cable tensions")
    fig = render("chi2_shares", plan, None)
    assert [t.get_text() for t in fig.axes[0].get_xticklabels()] == plan["ticks"]
    assert len(fig.axes[0].patches) == 2 * (3 + m)
    plt.close(fig)
    plan = _residual_plan(d, 6, next(iter(a["covariates"])))
    fig = render("residuals", plan, None)
    keep = np.asarray(a["keep"], bool)
    for ax in fig.axes[:2]:
        got = {c.get_label(): len(c.get_offsets()) for c in ax.collections if c.get_label().startswith("session")}
        assert got == {"session -3": int(np.sum(keep[n // 2:])), "session 7": int(np.sum(keep[:n // 2]))}
    plt.close(fig)


def test_fit_residual_plot_leaves_out_unrecorded_channels_and_marks_sessions(pulley_fit):
    import dataclasses

    import equinox as eqx
    import matplotlib.pyplot as plt

    from fitting.plots import residual_plot

    rec = pulley_fit.args[1]
    n = rec.l0.shape[0]
    split = n // 3
    fit = eqx.tree_at(lambda f: (f.args[1].pose_mask, f.args[1].session), pulley_fit,
                      (np.zeros((n, 6), bool), (np.arange(n) >= split).astype(np.int64)))
    fit = dataclasses.replace(fit, spec=dataclasses.replace(pulley_fit.spec, session_ids=(12, 40)))
    fig = residual_plot(fit)
    assert [ax.get_ylabel().split("\n")[0] for ax in fig.axes] == ["tension"]
    dashed = [ln for ln in fig.axes[0].get_lines() if ln.get_linestyle() == "--"]
    assert [ln.get_xdata()[0] for ln in dashed] == [split - 0.5]
    assert sorted(t.get_text() for t in fig.axes[0].texts) == ["session 12", "session 40"]
    assert "session" in fig.axes[-1].get_xlabel()
    plt.close(fig)
