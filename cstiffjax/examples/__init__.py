"""Bundled robot descriptions and recordings (``example_path(name)`` finds them)."""

from pathlib import Path

HERE = Path(__file__).parent


def example_path(name: str) -> Path:
    """Path of a bundled example file, e.g. ``example_path("prototype_8mm.toml")``."""
    p = HERE / name
    if not p.exists():
        avail = sorted(str(q.relative_to(HERE)) for q in HERE.rglob("*") if q.suffix in (".toml", ".csv"))
        raise FileNotFoundError(f"no bundled example {name!r}; available: {', '.join(avail)}")
    return p


def list_examples() -> list[str]:
    """Names of the bundled example files."""
    return sorted(str(q.relative_to(HERE)) for q in HERE.rglob("*") if q.suffix in (".toml", ".csv"))
