"""`cstiffjax diagnose ROBOT CSV` with neither --report nor --json leaves its report in ./diagnosis/."""

import json

from cstiffjax.examples import example_path


def test_diagnose_without_outputs_writes_the_report_folder(tmp_path, monkeypatch, capsys):
    import fitting.diagnosis.diagnose as dg
    from cstiffjax.commands.cli import main
    from fitting.diagnosis.report import validate_diagnosis

    real = dg.diagnose

    def short(robot, rec, **kw):  # the baseline only: no candidate effects, no search, no posterior
        return real(robot, rec, **kw, effects=(), discover=False, posterior_steps=0, folds=2)

    monkeypatch.setattr(dg, "diagnose", short)
    monkeypatch.chdir(tmp_path)
    rb, rc = (str(example_path(f"example02/{f}")) for f in ("robot.toml", "recordings.csv"))
    assert main(["diagnose", rb, rc]) == 0
    out, err = capsys.readouterr()
    assert "the report goes to ./diagnosis/" in err
    assert "none (give --report" not in out and "diagnosis/ (report.md, diagnosis.json, figures)" in out
    doc = validate_diagnosis(json.loads((tmp_path / "diagnosis" / "diagnosis.json").read_text()))
    assert doc["robot"] == "example02" and doc["effects"] == []
    assert (tmp_path / "diagnosis" / "report.md").stat().st_size > 0
    # with --json alone only that file is written
    assert main(["diagnose", rb, rc, "--json", str(tmp_path / "d.json"), "--quiet"]) == 0
    assert (tmp_path / "d.json").exists() and not (tmp_path / "d.json").is_dir()
