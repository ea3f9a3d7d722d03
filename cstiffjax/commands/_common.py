"""Helpers shared by the CLI commands: argument parsing and JSON output."""

import json
from pathlib import Path

import numpy as np

from ..examples import HERE, example_path


def resolve_path(p: str) -> Path:
    """A user path, or the name of a bundled example (``prototype_8mm.toml``)."""
    path = Path(p)
    if path.exists():
        return path
    if not path.is_absolute() and (HERE / p).exists():
        return example_path(p)
    raise FileNotFoundError(f"{p}: no such file (and no bundled example of that name)")


def to_jsonable(obj):
    """Convert arrays/scalars in nested containers to plain Python for ``json``."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [to_jsonable(v) for v in obj]
    if hasattr(obj, "shape") or isinstance(obj, np.generic):
        a = np.asarray(obj)
        return a.item() if a.ndim == 0 else a.tolist()
    return obj


def write_json(path, payload) -> None:
    Path(path).write_text(json.dumps(to_jsonable(payload), indent=1) + "\n")


def format_matrix(M, fmt="{:12.5g}") -> str:
    return "\n".join(" ".join(fmt.format(v) for v in row) for row in np.asarray(M))
