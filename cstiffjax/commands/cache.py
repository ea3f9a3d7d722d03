"""Show or clear the persistent compilation cache.

``cstiffjax cache info`` (the default) prints where the cache is, whether the command line
uses it and why (``$CSTIFFJAX_CACHE_DIR``, ``$XDG_CACHE_HOME`` or the default
``~/.cache/cstiffjax/jax``; ``CSTIFFJAX_CACHE_DIR=off`` turns it off), its size and its
entries: compiled XLA programs and serialized traced programs. ``cstiffjax cache clear``
removes the cache's own files (it asks nothing) and says what it removed; any other file in
the folder stays, and so does the folder. The next command compiles again and refills it.
``--json OUT`` also writes the same as JSON (``-``: to standard output, instead of the text).
"""

import json
import sys

from cstiffjax.commands.common import check_outputs, to_jsonable, write_json
from cstiffjax.runtime.cache import cache_info, clear_cache

NAME = "cache"
HELP = "show (info) or clear the compilation cache"
COMPILES = False  # the command line does not turn the cache on for this command


def add_arguments(p):
    p.add_argument("action", nargs="?", choices=("info", "clear"), default="info",
                   help="info: location, size, entries and whether it is on (default); clear: remove its files")
    p.add_argument("--json", metavar="OUT", help="also write the result as JSON ('-': standard output only)")


def _size(n: int) -> str:
    for unit in ("bytes", "kB", "MB", "GB"):
        if n < 1000 or unit == "GB":
            return f"{n} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1000
    return ""  # pragma: no cover


def _info(echo) -> dict:
    info = cache_info()
    out = {"folder": None if info.folder is None else str(info.folder), "enabled": info.enabled,
           "reason": info.reason, "exists": info.folder is not None and info.folder.is_dir(),
           "size_bytes": info.size_bytes, "entries": info.compiled + info.programs,
           "compiled": info.compiled, "programs": info.programs, "temporary": info.temporary,
           "other": info.other, "foreign": info.foreign}
    if info.folder is None:
        echo(f"compilation cache: off ({info.reason})")
        return out
    echo(f"compilation cache: {info.folder}")
    echo(f"  {'on' if info.enabled else 'off'} for the command line ({info.reason}); "
         "CSTIFFJAX_CACHE_DIR=off turns it off, CSTIFFJAX_CACHE_DIR=FOLDER moves it")
    if not out["exists"]:
        if info.enabled:
            echo("  empty: the folder does not exist yet")
        return out
    echo(f"  {_size(info.size_bytes)} in {out['entries']} entries: {info.compiled} compiled XLA programs, "
         f"{info.programs} serialized programs"
         + (f"; {info.temporary} temporary files" if info.temporary else "")
         + (f"; {info.other} bookkeeping files" if info.other else ""))
    if info.foreign:
        echo(f"  {info.foreign} other files in the folder are not the cache's (`cstiffjax cache clear` keeps them)")
    return out


def _clear(echo) -> tuple[dict, int]:
    done = clear_cache()
    out = {"folder": None if done.folder is None else str(done.folder), "removed": done.removed,
           "size_bytes": done.size_bytes, "failed": [[str(p), why] for p, why in done.failed],
           "kept_foreign": done.foreign}
    if done.folder is None:
        echo(f"compilation cache: off ({cache_info().reason}): nothing to clear")
        return out, 0
    r = done.removed
    echo(f"removed from {done.folder}: {r.get('compiled', 0)} compiled XLA programs, {r.get('programs', 0)} "
         f"serialized programs, {r.get('temporary', 0)} temporary and {r.get('other', 0)} bookkeeping files "
         f"({_size(done.size_bytes)})")
    if done.foreign:
        echo(f"kept {done.foreign} other files (not the cache's)")
    for p, why in done.failed:
        print(f"cstiffjax cache: error: could not remove {p}: {why}", file=sys.stderr)
    return out, 1 if done.failed else 0


def run(args) -> int:
    to_stdout = args.json == "-"
    if args.json and not to_stdout:
        check_outputs(files={"--json": args.json})
    echo = (lambda *a: None) if to_stdout else print
    if args.action == "clear":
        out, code = _clear(echo)
    else:
        out, code = _info(echo), 0
    if to_stdout:
        print(json.dumps(to_jsonable(out), indent=1))
    elif args.json:
        write_json(args.json, out)
    return code
