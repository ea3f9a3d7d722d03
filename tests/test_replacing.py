"""No earlier output is replaced unannounced: a folder output over an existing one says which
of its files it replaces (stderr), and says nothing when there was none."""

import fitting.diagnosis.diagnose
from cstiffjax.commands.cli import main
from cstiffjax.io.atomic import earlier_outputs, output_folder


def test_output_folder_announces_only_what_it_replaces(tmp_path):
    heard = []
    out = tmp_path / "report"
    with output_folder(out, ("report.md", "*.png"), on_replace=heard.append) as tmp:
        (tmp / "report.md").write_text("first")
    assert heard == []  # a new folder: nothing replaced
    (out / "notes.txt").write_text("the user's own file")
    with output_folder(out, ("report.md", "*.png"), on_replace=heard.append) as tmp:
        (tmp / "report.md").write_text("second")
    assert heard == [f"replacing 1 file(s) of an earlier run in {out}/: report.md"]
    assert (out / "notes.txt").read_text() == "the user's own file" and (out / "report.md").read_text() == "second"
    assert earlier_outputs(tmp_path / "missing", ("*",)) == []


def test_workspace_and_generate_say_they_replace_an_earlier_run(tmp_path, capsys):
    grid = ["--pose-grid", "-0.1", "0.1", "2", "-0.1", "0.1", "2", "0.8", "0.9", "2"]
    ws = ["workspace", "tcpr8.toml", "--kind", "wrench-closure", *grid, "--out", str(tmp_path / "ws"), "--quiet"]
    gen = ["generate", "--out", str(tmp_path / "gen"), "--samples", "3", "--seed", "5", "--quiet",
           "--cases", "proto_clean"]
    for argv in (ws, gen):
        assert main(argv) == 0
        assert "replacing" not in capsys.readouterr().err, argv[0]
        assert main(argv) == 0
        err = capsys.readouterr().err
        assert "note: replacing" in err and "of an earlier run in" in err, (argv[0], err)


def _once(monkeypatch, module, name, **fixed):
    """``module.name`` computed on its first call (with ``fixed`` keywords added) and returned
    again on later calls: the command's logic runs unchanged, its computation once."""
    real, kept = getattr(module, name), []

    def call(*args, **kwargs):
        if not kept:
            kept.append(real(*args, **{**kwargs, **fixed}))
        return kept[0]

    monkeypatch.setattr(module, name, call)


def _announced(argv, out, capsys) -> tuple[str, str]:
    """stderr of ``argv`` run into a new ``out``, then again over the first run's output."""
    assert not out.exists()
    assert main(argv) in (0, 3)
    first = capsys.readouterr().err
    assert out.is_dir()
    assert main(argv) in (0, 3)
    return first, capsys.readouterr().err


def test_diagnose_names_the_report_it_replaces(lab, tmp_path, monkeypatch, capsys):
    _once(monkeypatch, fitting.diagnosis.diagnose, "diagnose", effects=(), posterior_steps=0)  # the baseline only
    out = tmp_path / "rep"
    first, again = _announced(["diagnose", *map(str, lab), "--report", str(out), "--quiet"], out, capsys)
    assert "replacing" not in first, first
    note = next(line for line in again.splitlines() if "replacing" in line)
    assert note.startswith("note: replacing ") and f"of an earlier run in {out}/: " in note, again
    assert "diagnosis.json" in note and "report.md" in note


def test_fit_names_the_figures_it_replaces(lab, tmp_path, monkeypatch, capsys):
    import fitting.calibration.least_squares as least_squares

    _once(monkeypatch, least_squares, "calibrate")
    out = tmp_path / "plots"
    first, again = _announced(["fit", *map(str, lab), "--plots", str(out), "--quiet"], out, capsys)
    assert "replacing" not in first, first
    assert f"note: replacing 1 file(s) of an earlier run in {out}/: residuals.png" in again.splitlines(), again
