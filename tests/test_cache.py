"""The persistent cache (cstiffjax.runtime.cache, .store, .programs) never loses a run and never
serves a stale answer: processes started together on an empty cache, damaged entries, an
edited source under a warm cache, unusable folders, failed writes, ``--quiet`` and the
``cstiffjax cache`` command.

Most checks run the public API as a notebook would (:data:`PROBE`, a fresh interpreter:
``cstiffjax.enable_cache()``, a jitted ``stiffness_split`` served by JAX's compilation cache
and a serialized :class:`~cstiffjax.runtime.programs.Program`) and compare with an uncached
run and with the closed-form weight terms of the bundled tcpr8 robot (from its TOML)."""

import errno
import json
import os
import re
import shutil
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest

from cstiffjax.examples import example_path
from cstiffjax.runtime import cache, programs, store

from .helpers import forget_programs

ROOT = Path(__file__).resolve().parent.parent
PROBE = """
import json, os, sys, time
from pathlib import Path
import jax.numpy as jnp
import numpy as np
import cstiffjax
from cstiffjax.runtime import programs
from cstiffjax.statics import geometry

folder = cstiffjax.enable_cache()
robot = cstiffjax.load_robot(cstiffjax.example_path("tcpr8.toml"))
pose = jnp.array([0.0, 0.0, 0.5, 0.0, 0.0, 0.0])
barrier = os.environ.get("PROBE_BARRIER")  # a folder: processes started together compile together
if barrier:
    (Path(barrier) / f"ready.{os.getpid()}").touch()
    while not (Path(barrier) / "go").exists():
        time.sleep(0.002)
split = cstiffjax.stiffness_split(robot, pose, jnp.full(8, 150.0))
weight = programs.Program(geometry.gravity_wrench, name="tests.cache.gravity_wrench", like=lambda a: 0)(robot, pose)
print(json.dumps({"package": cstiffjax.__file__, "folder": None if folder is None else str(folder),
                  "K1": np.asarray(split.K1).tolist(), "K2": np.asarray(split.K2).tolist(),
                  "K_gravity": np.asarray(split.K_gravity).tolist(), "weight": np.asarray(weight).tolist()}))
"""
ANSWERS = ("K1", "K2", "K_gravity", "weight")


def _env(**set_):
    env = {k: v for k, v in os.environ.items()
           if k not in ("CSTIFFJAX_CACHE_DIR", "XDG_CACHE_HOME", "CSTIFFJAX_TEST_CACHE", "PROBE_BARRIER")}
    env["PYTHONPATH"] = str(ROOT)
    env.update({k: str(v) for k, v in set_.items()})
    return env


# Starts PROBE (argv[1]) in a fresh interpreter with a limit (set here: no fork of the
# multithreaded test process runs Python code): PROBE_LIMIT=no-bytes, every write fails
# (RLIMIT_FSIZE 0: EFBIG once a file is created, as on a full disk); read-only, as root,
# without the capabilities that ignore file permissions (exit 77 where they cannot be dropped).
LAUNCH = """
import ctypes, os, resource, sys
if os.environ["PROBE_LIMIT"] == "no-bytes":
    resource.setrlimit(resource.RLIMIT_FSIZE, (0, 0))
elif os.geteuid() == 0:
    libc = ctypes.CDLL(None, use_errno=True)
    if any(libc.prctl(24, cap, 0, 0, 0) != 0 for cap in (1, 2)):  # PR_CAPBSET_DROP: DAC_OVERRIDE, DAC_READ_SEARCH
        sys.exit(77)
os.execv(sys.executable, [sys.executable, "-c", sys.argv[1]])
"""


def _start(env):
    cmd = [sys.executable, "-c", LAUNCH, PROBE] if env.get("PROBE_LIMIT") else [sys.executable, "-c", PROBE]
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=env["PYTHONPATH"])  # `-c` puts the cwd first on the path


def _result(proc):
    out, err = proc.communicate(timeout=600)
    if proc.returncode == 77:
        pytest.skip("cannot drop root's file-permission capabilities here")
    assert proc.returncode == 0, err[-3000:]
    return json.loads(out.strip().splitlines()[-1]), err


def _probe(**env):
    return _result(_start(_env(**env)))


def _same(a, b):
    for k in ANSWERS:
        np.testing.assert_array_equal(np.asarray(a[k]), np.asarray(b[k]), err_msg=k)


def _weight_terms(factor=1.0):
    """Closed form, from the TOML: the weight ``f = m g`` at the centre of mass ``r`` (pose
    unrotated): wrench ``[f, r x f]`` and ``K_gravity`` (rotation block ``(f.r) I - r f^T``)."""
    data = tomllib.loads(example_path("tcpr8.toml").read_text())
    f = factor * data["platform"]["mass"] * np.asarray(data["gravity"], float)
    r = np.asarray(data["platform"]["com"], float)
    K = np.zeros((6, 6))
    K[3:, 3:] = f @ r * np.eye(3) - np.outer(r, f)
    return np.r_[f, np.cross(r, f)], K


def _files(folder):
    """``{relative path: (inode, mtime_ns, size)}`` of every file under ``folder``."""
    return {p.relative_to(folder).as_posix(): (p.stat().st_ino, p.stat().st_mtime_ns, p.stat().st_size)
            for p in sorted(Path(folder).rglob("*")) if p.is_file()}


def _kinds(folder):
    return {k: len(v) for k, v in store.own_files(Path(folder)).items()}


@pytest.fixture(scope="module")
def reference():
    """One run without the cache."""
    out, err = _probe(CSTIFFJAX_CACHE_DIR="off")
    assert out["folder"] is None and "Warning" not in err
    return out


def _warm(reference, **env):
    """A cache filled by one run (warm caches are made in place: JAX's keys include the
    folder's path, so a copied cache finds nothing)."""
    out, err = _probe(**env)
    assert "Warning" not in err, err
    _same(out, reference)
    return Path(out["folder"])


def test_answers_are_the_closed_form_weight_terms(reference):
    weight, K_gravity = _weight_terms()
    np.testing.assert_allclose(reference["weight"], weight, rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(reference["K_gravity"], K_gravity, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("n", [2, 3])
def test_processes_started_together_on_an_empty_cache(tmp_path, reference, n):
    """``n`` interpreters import, turn the cache on, wait for one another and then compile
    and write the same entries at once: none fails or warns, all get the uncached
    answers, and the cache is whole afterwards (one serialized program, no temporary
    file; a later run finds everything and writes nothing)."""
    barrier = tmp_path / "barrier"
    barrier.mkdir()
    env = _env(XDG_CACHE_HOME=tmp_path / "xdg", PROBE_BARRIER=barrier)
    procs = [_start(env) for _ in range(n)]
    deadline = time.monotonic() + 300
    while len(list(barrier.glob("ready.*"))) < n and time.monotonic() < deadline and all(
            p.poll() is None for p in procs):
        time.sleep(0.01)
    (barrier / "go").touch()
    results = [_result(p) for p in procs]
    folder = tmp_path / "xdg" / "cstiffjax" / "jax"
    for out, err in results:
        assert out["folder"] == str(folder)
        assert "Warning" not in err and "Error" not in err, err
        _same(out, reference)
    kinds = _kinds(folder)
    assert kinds["compiled"] >= 2 and kinds["programs"] == 1 and kinds["temporary"] == 0, kinds
    info = cache.cache_info(environ={"XDG_CACHE_HOME": str(tmp_path / "xdg")})
    assert (info.folder, info.enabled, info.compiled, info.programs) == (folder, True, kinds["compiled"], 1)
    before = _files(folder)
    out, err = _probe(XDG_CACHE_HOME=tmp_path / "xdg")
    _same(out, reference)
    assert _files(folder) == before and "Warning" not in err


def _damage(folder):
    """Truncate, overwrite and empty entries of every kind; ``{relative path: how}``."""
    done = {}
    compiled = store.own_files(folder)["compiled"]
    assert len(compiled) >= 3
    for path, how in zip(sorted(compiled, key=lambda p: -p.stat().st_size), ("truncated", "garbage", "empty")):
        data = path.read_bytes()
        path.write_bytes({"truncated": data[: len(data) // 2], "garbage": b"not an XLA program\n" * 50,
                          "empty": b""}[how])
        done[path.relative_to(folder).as_posix()] = how
    (prog,) = store.own_files(folder)["programs"]
    prog.write_bytes(prog.read_bytes()[:-100])
    done[prog.relative_to(folder).as_posix()] = "truncated"
    return done


def test_damaged_entries_are_ignored_with_a_warning_and_rewritten(tmp_path, reference):
    """In the documented default place (``~/.cache/cstiffjax/jax`` of a fresh ``$HOME``): a
    truncated, overwritten or emptied XLA entry and a truncated serialized program: the
    next run warns about each, gives the uncached answers and rewrites them; the run after
    it neither warns nor writes anything (JAX's own file cache never replaced a damaged
    entry: it warned and compiled on every run)."""
    folder = _warm(reference, HOME=tmp_path)
    assert folder == tmp_path / ".cache" / "cstiffjax" / "jax"
    whole = _files(folder)
    damaged = _damage(folder)
    out, err = _probe(HOME=tmp_path)
    _same(out, reference)
    assert len(re.findall(r"\w+Warning: ", err)) == len(damaged), err
    for name in damaged:
        assert name.rsplit("/", 1)[-1] in err or name.rsplit("-", 2)[0] in err, (name, err)
    after = _files(folder)
    assert set(after) == set(whole)  # all there again, nothing else
    assert all(after[name][2] > 100 for name in damaged)
    out, err = _probe(HOME=tmp_path)
    _same(out, reference)
    assert "Warning" not in err and _files(folder) == after


def _cli(*args, **env):
    return subprocess.run([sys.executable, "-m", "cstiffjax.commands.cli", *args], env=_env(**env),
                          capture_output=True, text=True)


def test_the_command_line_names_a_damaged_entry_in_one_line_also_when_quiet(tmp_path):
    """A compressed XLA entry cut short (found by JAX's decompression, which warns): one line
    on standard error under ``--quiet`` too, the entry rewritten, the same answer."""
    folder = tmp_path / "c"
    argv = ["stiffness", "tcpr8.toml", "--pose", "0", "0", "0.5", "0", "0", "0", "--quiet", "--json"]
    first = _cli(*argv, tmp_path / "a.json", CSTIFFJAX_CACHE_DIR=folder)
    assert first.returncode == 0 and first.stderr == "", first.stderr
    (entry,) = [p for p in store.own_files(folder)["compiled"] if p.name.startswith("jit_stiffness_split-")]
    entry.write_bytes(entry.read_bytes()[:1000])
    again = _cli(*argv, tmp_path / "b.json", CSTIFFJAX_CACHE_DIR=folder)
    assert again.returncode == 0
    (line,) = again.stderr.splitlines()
    assert line.startswith("cstiffjax stiffness: warning: ignored an unreadable compilation cache entry for "
                           "'jit_stiffness_split': ") and line.endswith("; compiled it again and rewrote it"), line
    assert entry.stat().st_size > 1000  # rewritten
    assert json.loads((tmp_path / "a.json").read_text()) == json.loads((tmp_path / "b.json").read_text())


def test_an_edited_source_under_a_warm_cache_gives_the_edited_answer(tmp_path, reference):
    """A copy of the packages runs on a warm cache (the same source: the same keys, nothing
    new written); then the weight in ``gravity_wrench`` is doubled in the copy: new keys,
    and the answers are the closed-form ones of the doubled weight, never the cached ones."""
    folder = _warm(reference, CSTIFFJAX_CACHE_DIR=tmp_path / "c")
    warm = _files(folder)
    for pkg in ("cstiffjax", "fitting"):
        shutil.copytree(ROOT / pkg, tmp_path / "src" / pkg, ignore=shutil.ignore_patterns("__pycache__", "*.csv"))
    out, err = _probe(CSTIFFJAX_CACHE_DIR=folder, PYTHONPATH=tmp_path / "src")
    assert out["package"] == str(tmp_path / "src" / "cstiffjax" / "__init__.py")
    _same(out, reference)
    assert _files(folder) == warm and "Warning" not in err
    geometry = tmp_path / "src" / "cstiffjax" / "statics" / "geometry.py"
    text = geometry.read_text()
    line = "    f = robot.weight\n    return jnp.concatenate([f, jnp.cross(R @ robot.com, f)])"
    assert text.count(line) == 1, "gravity_wrench changed: update this test's edit"
    geometry.write_text(text.replace(line, line.replace("f = robot.weight", "f = 2.0 * robot.weight")))
    edited, err = _probe(CSTIFFJAX_CACHE_DIR=folder, PYTHONPATH=tmp_path / "src")
    assert "Warning" not in err, err
    weight, K_gravity = _weight_terms(factor=2.0)
    np.testing.assert_allclose(edited["weight"], weight, rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(edited["K_gravity"], K_gravity, rtol=1e-12, atol=1e-12)
    for k in ("K1", "K2"):  # the cables' terms do not depend on the weight
        np.testing.assert_array_equal(edited[k], reference[k])
    kinds = _kinds(folder)
    assert kinds["programs"] == 2 and kinds["compiled"] > len(warm) - 1, (kinds, warm)


def test_a_read_only_cache_folder_warns_and_runs_uncached(tmp_path, reference):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o555)
    out, err = _probe(CSTIFFJAX_CACHE_DIR=folder, PROBE_LIMIT="read-only")
    assert out["folder"] is None
    _same(out, reference)
    assert err.count("CacheWarning") == 1 and f"compilation cache {folder}: cannot write there" in err, err
    assert "running without the cache" in err and list(folder.iterdir()) == []


@pytest.mark.parametrize("below", [False, True])
def test_a_cache_path_that_is_a_file_warns_and_leaves_jax_alone(tmp_path, below):
    import jax

    (tmp_path / "f").write_text("a file\n")
    folder = tmp_path / "f" / "jax" if below else tmp_path / "f"
    before = jax.config.jax_compilation_cache_dir
    with pytest.warns(store.CacheWarning) as seen:
        assert cache.enable_compilation_cache(folder) is None
    (w,) = [w for w in seen if w.category is store.CacheWarning]
    what = f"{tmp_path / 'f'} is a file" if below else "it is a file"
    assert str(w.message) == (f"compilation cache {folder}: {what}, not a folder; running without the cache (set "
                              "$CSTIFFJAX_CACHE_DIR to a writable folder, or to off)")
    assert jax.config.jax_compilation_cache_dir == before and programs.folder() is None
    assert (tmp_path / "f").read_text() == "a file\n"


def test_the_command_line_says_in_one_line_that_it_runs_without_the_cache(tmp_path, monkeypatch, capsys):
    from cstiffjax.commands import check, cli

    (tmp_path / "f").write_text("")
    monkeypatch.setenv("CSTIFFJAX_CACHE_DIR", str(tmp_path / "f"))
    monkeypatch.setattr(check, "run", lambda args: 0)
    assert cli.main(["check", "tcpr8.toml", "--quiet"]) == 0
    assert capsys.readouterr().err.splitlines() == [
        f"cstiffjax check: warning: compilation cache {tmp_path / 'f'}: it is a file, not a folder; running "
        "without the cache (set $CSTIFFJAX_CACHE_DIR to a writable folder, or to off)"]


class _FullDisk:
    """``open`` of a full disk: the file is created (0 bytes), writing to it fails."""

    def __init__(self, path, mode):
        self.f = open(path, mode)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.f.close()

    def write(self, data):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_a_failed_write_leaves_no_temporary_file_and_warns_once(tmp_path, monkeypatch):
    import jax.numpy as jnp

    from cstiffjax.io.robot_io import load_robot
    from cstiffjax.statics import geometry

    monkeypatch.setattr(store, "open", _FullDisk, raising=False)
    robot, pose = load_robot(example_path("tcpr8.toml")), jnp.array([0.0, 0.0, 0.5, 0.0, 0.0, 0.0])
    programs.set_folder(tmp_path / "programs")
    try:
        prog = programs.Program(geometry.gravity_wrench, name="tests.cache.full_disk", like=lambda a: 0)
        with pytest.warns(store.CacheWarning, match="No space left on device") as seen:
            out = prog(robot, pose)
            forget_programs()
            prog(robot, pose)  # a second failure: no second warning
            for _ in range(2):
                store.XlaStore(tmp_path).put("jit_f-" + "0" * 64, b"\x78\x9c executable")
    finally:
        programs.set_folder(None)
        forget_programs()
    np.testing.assert_array_equal(out, _weight_terms()[0])
    assert len([w for w in seen if w.category is store.CacheWarning]) == 2  # once per folder
    assert [p.name for p in tmp_path.rglob("*") if p.is_file()] == []


def test_a_full_disk_in_a_real_process(tmp_path, reference):
    """No byte can be written (``RLIMIT_FSIZE`` 0: every write fails with EFBIG after the
    file is created): the run gives the uncached answers, warns once per folder, and
    leaves no file behind."""
    out, err = _probe(CSTIFFJAX_CACHE_DIR=tmp_path / "c", PROBE_LIMIT="no-bytes")
    _same(out, reference)
    assert err.count("CacheWarning") == 2 and err.count("could not write") == 2, err
    assert [p.name for p in (tmp_path / "c").rglob("*") if p.is_file()] == []


def test_temporary_files_of_killed_processes_are_removed_after_an_hour(tmp_path):
    key = "a" * 64
    old = [tmp_path / f"jit_f-{key}-cache.12.34.tmp", tmp_path / "programs" / f"{key}.jaxexport.5.6.tmp"]
    young = tmp_path / "programs" / f"{key}.jaxexport.7.8.tmp"
    foreign = tmp_path / "mine.tmp"
    for p in (*old, young, foreign):
        p.parent.mkdir(exist_ok=True)
        p.write_bytes(b"")
    for p in (*old, foreign):
        os.utime(p, (time.time() - 7200, time.time() - 7200))
    with cache.compilation_cache(tmp_path) as folder:
        assert folder == tmp_path
    assert [p.exists() for p in (*old, young, foreign)] == [False, False, True, True]


_GPU_HERE = """
import sys
from jax._src import hardware_utils
hardware_utils.has_visible_nvidia_gpu = lambda: True  # as on a machine with an NVIDIA GPU and a CPU jaxlib
from cstiffjax.commands import cli
sys.exit(cli.main(sys.argv[1:]))
"""


def test_quiet_hides_jax_own_warnings(tmp_path):
    """JAX's "An NVIDIA GPU may be present on this machine, but a CUDA-enabled jaxlib is not
    installed" (a log message at start-up) is shown without ``--quiet`` and not with it."""
    runs = [subprocess.run([sys.executable, "-c", _GPU_HERE, "check", "tcpr8.toml", *q], env=_env(
        CSTIFFJAX_CACHE_DIR=tmp_path), capture_output=True, text=True, cwd=ROOT) for q in ([], ["--quiet"])]
    assert [r.returncode for r in runs] == [0, 0], runs[0].stderr + runs[1].stderr
    assert "NVIDIA GPU may be present" in runs[0].stderr
    assert runs[1].stderr == ""


def _fill(folder):
    """Files of every kind the cache holds, and one of the user's; ``{kind: bytes}``."""
    key = "b" * 64
    files = {f"jit_f-{key}-cache": ("compiled", 300), f"jit_g-{'c' * 64}-cache": ("compiled", 200),
             f"programs/{key}.jaxexport": ("programs", 50), f"programs/{key}.jaxexport.1.2.tmp": ("temporary", 0),
             f"jit_f-{key}-atime": ("other", 8), "notes.txt": ("foreign", 10), f"programs/{key}.txt": ("foreign", 1)}
    for name, (_, size) in files.items():
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_bytes(b"x" * size)
    return files


def test_cache_info_and_clear(tmp_path, monkeypatch, capsys):
    from cstiffjax.commands import cli

    folder = tmp_path / "c"
    monkeypatch.setenv("CSTIFFJAX_CACHE_DIR", str(folder))
    assert "cache" in cli.COMMANDS
    assert cli.main(["cache", "info", "--json", "-"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert (info["folder"], info["exists"], info["entries"], info["enabled"]) == (str(folder), False, 0, True)
    assert not folder.exists()  # looking creates nothing
    files = _fill(folder)
    assert cli.main(["cache"]) == 0
    text = capsys.readouterr().out
    assert f"compilation cache: {folder}" in text and "on for the command line" in text
    assert "location from $CSTIFFJAX_CACHE_DIR" in text
    assert "3 entries: 2 compiled XLA programs, 1 serialized programs" in text and "558 bytes" in text
    assert cli.main(["cache", "info", "--json", str(tmp_path / "info.json")]) == 0
    info = json.loads((tmp_path / "info.json").read_text())
    assert {k: info[k] for k in ("compiled", "programs", "temporary", "other", "foreign", "size_bytes")} == {
        "compiled": 2, "programs": 1, "temporary": 1, "other": 1, "foreign": 2, "size_bytes": 558}
    capsys.readouterr()
    assert cli.main(["cache", "clear"]) == 0
    assert capsys.readouterr().out.splitlines() == [
        f"removed from {folder}: 2 compiled XLA programs, 1 serialized programs, 1 temporary and 1 bookkeeping files "
        "(558 bytes)", "kept 2 other files (not the cache's)"]
    left = sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file())
    assert left == sorted(n for n, (kind, _) in files.items() if kind == "foreign")
    assert cli.main(["cache", "clear", "--json", "-"]) == 0
    assert json.loads(capsys.readouterr().out)["removed"] == {"compiled": 0, "programs": 0, "temporary": 0, "other": 0}
    monkeypatch.setenv("CSTIFFJAX_CACHE_DIR", "off")
    assert cli.main(["cache", "clear"]) == 0 and cli.main(["cache", "info"]) == 0
    out = capsys.readouterr().out
    assert "nothing to clear" in out and "off (turned off by $CSTIFFJAX_CACHE_DIR='off')" in out


def test_the_cache_command_does_not_turn_the_cache_on(tmp_path, monkeypatch):
    import jax

    from cstiffjax.commands import cli

    monkeypatch.setenv("CSTIFFJAX_CACHE_DIR", str(tmp_path / "c"))
    seen = []
    monkeypatch.setattr("cstiffjax.commands.cache.clear_cache",
                        lambda: seen.append(jax.config.jax_compilation_cache_dir) or cache.Cleared(None, {}, 0, (), 0))
    assert cli.main(["cache", "clear", "--quiet"]) == 0
    assert seen == [jax.config.jax_compilation_cache_dir] and seen[0] != str(tmp_path / "c")
    assert not (tmp_path / "c").exists()


def test_the_api_reports_the_cache_in_use(tmp_path):
    import cstiffjax

    assert cstiffjax.cache_info(tmp_path / "c").in_use is False
    with cache.compilation_cache(tmp_path / "c") as folder:
        info = cstiffjax.cache_info(folder)
        assert (info.folder, info.enabled, info.in_use) == (tmp_path / "c", True, True)
        assert "cache_info" in cstiffjax.__all__ and "enable_cache" in cstiffjax.__all__
    assert cstiffjax.cache_info(tmp_path / "c").in_use is False
