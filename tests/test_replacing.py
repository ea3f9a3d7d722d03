"""No earlier output is replaced unannounced: a folder output over an existing one says which
of its files it replaces (stderr), and says nothing when there was none."""

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
