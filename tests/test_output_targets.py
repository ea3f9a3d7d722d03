"""Where an output goes: a character device or a FIFO is written through and stays what it is,
any other special file is refused; a file output whose parent is a file says so; a folder
output replaces only what the run writes; a run with two outputs that fails on the second
names both (and diagnose still prints its verdict); paths printed back are escaped; ``fit``
shows cache warnings. Device nodes and FIFOs are private ones made in a temporary folder."""

import functools
import json
import os
import re
import socket
import stat
import threading

import pytest

import fitting.diagnosis.diagnose
from cstiffjax.commands.cli import main
from cstiffjax.core.errors import OutputPathError
from cstiffjax.io import atomic

POSE = ["--pose", "0", "0", "0.8", "0", "0", "0"]
TENSIONS = ["tensions", "tcpr8.toml", *POSE, "--method", "qp"]


def _device(path, minor: int):
    """A private character device node: ``(1, 3)`` is a null device, ``(1, 7)`` a full one."""
    os.mknod(path, stat.S_IFCHR | 0o666, os.makedev(1, minor))
    return path


def _is_device(path) -> bool:
    return stat.S_ISCHR(os.stat(path).st_mode)


class _Reader:
    """Reads a FIFO to its end in a daemon thread (so a writer never waits forever for a reader,
    and a test never waits forever for a writer: :meth:`text` gives up after a timeout)."""

    def __init__(self, fifo):
        self.data, self.fifo = [], fifo
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self):
        with open(self.fifo, "rb") as fh:
            self.data.append(fh.read())

    def text(self) -> str:
        self.thread.join(timeout=60)
        assert not self.thread.is_alive(), "nothing was written into the FIFO"
        return self.data[0].decode()


def _only(folder, *names):
    assert sorted(p.name for p in folder.iterdir()) == sorted(names)  # no temporary file left


# ------------------------------------------------------------- character devices and FIFOs
def test_a_null_device_is_written_through_and_stays_a_device(tmp_path, capsys):
    dev = _device(tmp_path / "null", 3)
    assert main([*TENSIONS, "--json", str(dev)]) == 0
    assert _is_device(dev) and f"wrote {dev}" in capsys.readouterr().out
    atomic.write_text(dev, "x" * 10_000)
    assert _is_device(dev)
    _only(tmp_path, "null")


def test_a_full_device_is_exit_4_and_stays_a_device(tmp_path, capsys):
    dev = _device(tmp_path / "full", 7)
    assert main([*TENSIONS, "--json", str(dev)]) == 4
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{dev}: No space left on device" in err and "Traceback" not in err
    assert _is_device(dev)
    _only(tmp_path, "full")


def test_a_fifo_gets_the_whole_document_and_stays_a_fifo(tmp_path, capsys):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    reader = _Reader(fifo)
    assert main([*TENSIONS, "--json", str(fifo)]) == 0
    doc = json.loads(reader.text())
    reference = tmp_path / "t.json"  # the same command into a regular file
    assert main([*TENSIONS, "--json", str(reference)]) == 0
    assert doc == json.loads(reference.read_text())
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    _only(tmp_path, "pipe", "t.json")


def test_a_socket_is_refused(tmp_path, capsys):
    path = tmp_path / "sock"
    with socket.socket(socket.AF_UNIX) as s:
        s.bind(str(path))
        assert main([*TENSIONS, "--json", str(path)]) == 1
        err = capsys.readouterr().err
        assert f"--json {path}: is neither a regular file, a character device nor a FIFO" in err
        assert stat.S_ISSOCK(os.stat(path).st_mode)
        with pytest.raises(OutputPathError, match="neither a regular file"):
            atomic.write_text(path, "x")


def test_special_files_inside_a_folder_output(tmp_path):
    """A FIFO among a folder output's files is written through (the folder is updated file by
    file), a FIFO of an earlier run's name that this run does not write is left alone, and a
    socket among them stops the run before anything is written or announced."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "b.txt").write_text("old b")
    os.mkfifo(out / "a.txt")
    os.mkfifo(out / "c.txt")
    reader, heard = _Reader(out / "a.txt"), []
    with atomic.output_folder(out, ("a.txt", "b.txt", "c.txt"), on_replace=heard.append) as tmp:
        (tmp / "a.txt").write_text("new a")
        (tmp / "b.txt").write_text("new b")
    assert reader.text() == "new a" and (out / "b.txt").read_text() == "new b"
    assert stat.S_ISFIFO(os.stat(out / "a.txt").st_mode) and stat.S_ISFIFO(os.stat(out / "c.txt").st_mode)
    assert heard == [f"replacing 1 file(s) of an earlier run in {out}/: b.txt"]  # the FIFOs are not replaced
    _only(out, "a.txt", "b.txt", "c.txt")
    with socket.socket(socket.AF_UNIX) as s:
        s.bind(str(out / "d.txt"))
        with pytest.raises(OutputPathError, match="d.txt: is neither"):
            with atomic.output_folder(out, ("b.txt", "d.txt"), on_replace=heard.append):
                raise AssertionError("the body must not run")
    assert (out / "b.txt").read_text() == "new b" and len(heard) == 1


def test_a_null_device_inside_a_plots_folder(lab, tmp_path):
    """``fit --plots DIR`` whose ``residuals.png`` is a null device: written through, still a device."""
    robot, rec = lab
    out = tmp_path / "plots"
    out.mkdir()
    dev = _device(out / "residuals.png", 3)
    assert main(["fit", str(robot), str(rec), "--plots", str(out), "--max-steps", "5", "--quiet"]) == 0
    assert _is_device(dev)
    _only(out, "residuals.png")


# ------------------------------------------------------------ a parent that is a file
def test_json_under_a_file_names_the_parent(tmp_path, capsys):
    (tmp_path / "a.json").write_text("mine")
    for target in (tmp_path / "a.json" / "k.json", tmp_path / "a.json" / "sub" / "k.json"):
        assert main([*TENSIONS, "--json", str(target)]) == 1
        err = capsys.readouterr().err
        assert f"--json {target}: its parent {tmp_path / 'a.json'} is a file, not a folder" in err, err
    assert (tmp_path / "a.json").read_text() == "mine"


# ------------------------------------------------------------ fit --plots keeps the user's files
def test_fit_plots_never_removes_a_file_it_does_not_write(lab, tmp_path, capsys):
    robot, rec = lab
    out = tmp_path / "plots"
    out.mkdir()
    (out / "corner.png").write_bytes(b"my corner plot")
    (out / "trace.png").write_bytes(b"my trace plot")
    argv = ["fit", str(robot), str(rec), "--plots", str(out), "--max-steps", "5", "--quiet"]
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert "replacing" not in err, err
    assert (out / "corner.png").read_bytes() == b"my corner plot"
    assert (out / "trace.png").read_bytes() == b"my trace plot"
    assert (out / "residuals.png").read_bytes()[:4] == b"\x89PNG"
    assert main(argv) == 0
    assert "replacing 1 file(s) of an earlier run in" in capsys.readouterr().err
    _only(out, "corner.png", "trace.png", "residuals.png")


# ------------------------------------------------------------ two outputs, the second fails
def test_a_full_disk_on_the_second_output_names_both_and_prints_the_verdict(lab, tmp_path, capsys, monkeypatch):
    """``--json k.json --report DIR``: the JSON is written, the report hits a full disk (a file
    limit set in a child process; here: the report's own writes fail with ENOSPC). Exit 4, the
    verdict printed, the written JSON and the unwritten report named; the earlier report kept."""
    import errno

    import fitting.diagnosis.report as report

    monkeypatch.setattr(fitting.diagnosis.diagnose, "diagnose",
                        functools.partial(fitting.diagnosis.diagnose.diagnose, effects=(), posterior_steps=0))
    js, rep = tmp_path / "k.json", tmp_path / "rep"
    argv = ["diagnose", *map(str, lab), "--json", str(js), "--report", str(rep)]
    assert main(argv) == 0
    before = {p.name: p.read_bytes() for p in rep.iterdir()}
    capsys.readouterr()
    js.write_text("earlier")

    def full(path, text):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(report, "write_text", full)
    assert main(argv) == 4
    out, err = capsys.readouterr()
    assert re.search(r"^explained (yes|no); final chi2/dof \d", out, re.M), out  # the verdict line
    assert f"NOT written: {rep}/" in out
    last = err.splitlines()[-1]
    assert "No space left on device" in last and f"written before it: {js}" in last, err
    assert json.loads(js.read_text())["robot"]  # the new JSON, complete
    assert {p.name: p.read_bytes() for p in rep.iterdir()} == before


def test_two_outputs_in_a_process_with_a_file_size_limit(tmp_path):
    """The real thing: ``RLIMIT_FSIZE`` set in a child, the second output larger than it."""
    import subprocess
    import sys
    import textwrap
    from pathlib import Path

    small, big = tmp_path / "k.json", tmp_path / "big.json"
    code = textwrap.dedent(f"""
        import resource, sys
        from cstiffjax.io import atomic
        from cstiffjax.commands.cli import _write_error
        written = []
        resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
        try:
            with atomic.recorded(written):
                atomic.write_text({str(small)!r}, "small")
                atomic.write_text({str(big)!r}, "x" * 100_000)
        except OSError as e:
            print(_write_error(e, written))
    """)
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    line = out.stdout.strip()
    assert line.startswith(f"error: {big}: File too large (not written") and f"written before it: {small}" in line, (
        line, out.stderr[-2000:])
    assert small.read_text() == "small" and not big.exists()
    _only(tmp_path, "k.json")


# ------------------------------------------------------------ paths printed back
def test_paths_printed_back_are_escaped(tmp_path, capsys):
    out = tmp_path / "evil\x1b[2J\nwrote nothing.json"
    assert main([*TENSIONS, "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "\x1b" not in printed and "\\x1b[2J\\nwrote nothing.json" in printed
    assert json.loads(out.read_text())


# ------------------------------------------------------------ fit's warnings
def test_fit_shows_a_cache_warning_and_not_its_own_weak_pairs_twice(lab, capsys, monkeypatch):
    """A cache warning issued while ``fit`` calibrates (a full disk under the compilation cache)
    is one line on stderr, as in every command; an identifiability warning (which the fit
    prints itself on stdout, from ``fit.weak``) is not shown again on stderr."""
    import warnings

    import fitting.calibration.least_squares as least_squares
    from cstiffjax.runtime.store import CacheWarning

    real = least_squares.calibrate

    def calibrate(*args, **kwargs):
        warnings.warn("could not write the cache entry x: No space left on device", CacheWarning, stacklevel=2)
        warnings.warn("weak pair: a and b", least_squares.IdentifiabilityWarning, stacklevel=2)
        return real(*args, **kwargs)

    monkeypatch.setattr(least_squares, "calibrate", calibrate)
    assert main(["fit", *map(str, lab), "--max-steps", "5", "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "cstiffjax fit: warning: could not write the cache entry x: No space left on device" in err.splitlines()
    assert "weak pair" not in err, err
