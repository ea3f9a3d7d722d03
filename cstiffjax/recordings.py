"""Load the recordings CSV of ``shared/spec/formats.md`` §2 into a :class:`Recordings`.

Column order is free; unknown numeric columns are kept as covariates. Every error is
a :class:`~cstiffjax.errors.RecordingsError` naming the file, the 1-based data row (the
header is row 0, as a spreadsheet shows it minus one) and the column.
"""

import csv
import math
from pathlib import Path

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from .errors import RecordingsError

_POS = ("x", "y", "z")
_ROT = ("rx", "ry", "rz")
_FORCE = ("fx", "fy", "fz")
_MOMENT = ("mx", "my", "mz")
_CSJM_MOMENT = ("tx", "ty", "tz")


def _f64(x):
    return jnp.asarray(x, dtype=jnp.float64)


class Recordings(eqx.Module):
    """Static equilibrium samples, in the order they were taken (``n`` rows).

    **Inputs:** ``l0`` ``(n, m)`` commanded unstrained lengths, m (zeros for a CSJM);
    ``wrench`` ``(n, 6)`` external ``[fx, fy, fz, mx, my, mz]`` on the platform, base
    frame, about the reference point, N and N·m (weight excluded); ``time`` ``(n,)`` s
    (``nan`` when the file has no ``time`` column).

    **Measurements:** ``pose`` ``(n, 6)`` ``[x, y, z, rx, ry, rz]`` (m, rad; position is
    zero for a CSJM); ``tensions`` ``(n, m)`` N at the exit point with ``tension_mask``
    true where a value was recorded; ``moment`` ``(n, 3)`` CSJM moment about O in the
    platform frame, N·m (zeros for a CDPR).

    ``covariates`` ``(n, k)`` holds any other numeric column, named by the static
    ``covariate_names``. ``source`` and ``dropped_rows`` (static) say where the data came
    from and which data rows (1-based) were dropped by ``drop_invalid``.
    """

    l0: Float[Array, "n m"] = eqx.field(converter=_f64)
    wrench: Float[Array, "n 6"] = eqx.field(converter=_f64)
    pose: Float[Array, "n 6"] = eqx.field(converter=_f64)
    tensions: Float[Array, "n m"] = eqx.field(converter=_f64)
    tension_mask: Bool[Array, "n m"] = eqx.field(converter=jnp.asarray)
    moment: Float[Array, "n 3"] = eqx.field(converter=_f64)
    time: Float[Array, " n"] = eqx.field(converter=_f64)
    covariates: Float[Array, "n k"] = eqx.field(converter=_f64)
    covariate_names: tuple[str, ...] = eqx.field(static=True, default=())
    kind: str = eqx.field(static=True, default="cdpr")
    source: str = eqx.field(static=True, default="<memory>")
    dropped_rows: tuple[int, ...] = eqx.field(static=True, default=())

    def __check_init__(self):
        n, m = self.l0.shape
        for name, shape in (("wrench", (n, 6)), ("pose", (n, 6)), ("tensions", (n, m)),
                            ("tension_mask", (n, m)), ("moment", (n, 3)), ("time", (n,))):
            if getattr(self, name).shape != shape:
                raise ValueError(f"Recordings.{name} must have shape {shape}, "
                                 f"got {getattr(self, name).shape}")
        if self.covariates.shape != (n, len(self.covariate_names)):
            raise ValueError("Recordings.covariates does not match covariate_names")

    @property
    def num_samples(self) -> int:
        return self.l0.shape[0]

    @property
    def num_cables(self) -> int:
        return self.l0.shape[1]

    @property
    def has_tensions(self) -> bool:
        return bool(np.any(np.asarray(self.tension_mask)))

    def covariate(self, name: str) -> np.ndarray:
        """The covariate column ``name`` (``KeyError`` lists the available ones)."""
        if name not in self.covariate_names:
            raise KeyError(f"no covariate {name!r}; available: {list(self.covariate_names)}")
        return np.asarray(self.covariates[:, self.covariate_names.index(name)])

    def select(self, index) -> "Recordings":
        """A subset of the samples (boolean mask or integer indices)."""
        idx = np.asarray(index)
        fields = ("l0", "wrench", "pose", "tensions", "tension_mask", "moment", "time", "covariates")
        return eqx.tree_at(lambda r: [getattr(r, f) for f in fields], self,
                           [getattr(self, f)[idx] for f in fields])


def _parse(cell: str):
    s = cell.strip()
    if s == "":
        return None
    try:
        v = float(s)
    except ValueError:
        return s  # non-numeric marker, reported by the caller
    return v


def load_recordings(path, robot, *, drop_invalid: bool = False) -> Recordings:
    """Load a recordings CSV for ``robot``.

    **Arguments:**

    - ``path``: the CSV file (formats.md §2).
    - ``robot``: the :class:`~cstiffjax.robot.CableRobot` or
      :class:`~cstiffjax.robot.SphericalJointModule` it was recorded on (fixes ``m``).
    - ``drop_invalid``: drop rows with a missing or non-numeric value in a required
      column (and rows with a non-numeric optional value) instead of raising; the
      returned ``dropped_rows`` lists them.

    **Returns:** a :class:`Recordings`.

    **Raises:** :class:`RecordingsError` naming file, row and column.
    """
    path = Path(path)
    m, kind = robot.num_cables, robot.kind
    try:
        with path.open(newline="") as fh:
            rows = list(csv.reader(fh))
    except OSError as e:
        raise RecordingsError(f"{path}: cannot read recordings: {e.strerror}") from None
    rows = [r for r in rows if any(c.strip() for c in r)]
    if not rows:
        raise RecordingsError(f"{path}: empty file; expected a header row and data rows")
    header = [h.strip() for h in rows[0]]
    seen = set()
    for j, h in enumerate(header, 1):
        if h == "":
            raise RecordingsError(f"{path}: header column {j} is empty; every column needs a name")
        if h in seen:
            raise RecordingsError(f"{path}: header names column '{h}' twice")
        seen.add(h)
    l0_cols = tuple(f"l0_{i}" for i in range(1, m + 1))
    t_cols = tuple(f"t_{i}" for i in range(1, m + 1))
    required = (*_ROT, *_CSJM_MOMENT) if kind == "csjm" else (*l0_cols, *_POS, *_ROT)
    missing = [c for c in required if c not in seen]
    if missing:
        raise RecordingsError(
            f"{path}: required column(s) missing for a {kind} with {m} cables: {', '.join(missing)}"
        )
    for h in header:  # cable columns beyond the robot's count
        for prefix in ("l0_", "t_"):
            if h.startswith(prefix) and h[len(prefix):].isdigit() and int(h[len(prefix):]) > m:
                raise RecordingsError(
                    f"{path}: column '{h}' refers to cable {h[len(prefix):]} but the robot "
                    f"'{robot.name}' has {m} cables (allowed: {prefix}1..{prefix}{m})"
                )
    known = set(l0_cols + t_cols + _POS + _ROT + _FORCE + _MOMENT + _CSJM_MOMENT + ("time",))
    cov_names = tuple(h for h in header if h not in known)
    req = set(required)
    cols = {h: [] for h in header}
    dropped = []
    for i, raw in enumerate(rows[1:], 1):
        if len(raw) != len(header):
            msg = f"{path}: row {i}: has {len(raw)} cells, the header has {len(header)}"
            if drop_invalid:
                dropped.append(i)
                continue
            raise RecordingsError(msg)
        vals = [_parse(c) for c in raw]
        bad = None
        for h, v in zip(header, vals, strict=True):
            if isinstance(v, str) or (v is not None and not math.isfinite(v)):
                bad = (h, f"value {raw[header.index(h)]!r} is not a finite number")
            elif v is None and h in req:
                bad = (h, "value is missing (empty cell) in a required column")
            if bad:
                break
        if bad:
            if drop_invalid:
                dropped.append(i)
                continue
            raise RecordingsError(
                f"{path}: row {i}, column '{bad[0]}': {bad[1]}; pass drop_invalid=True "
                f"(--drop-invalid) to drop such rows"
            )
        for h, v in zip(header, vals, strict=True):
            cols[h].append(np.nan if v is None else v)
    n = len(rows) - 1 - len(dropped)
    if n == 0:
        raise RecordingsError(f"{path}: no valid data rows (dropped {len(dropped)})")

    def block(names, fill=0.0):
        return np.stack([np.asarray(cols[c]) if c in cols else np.full(n, fill) for c in names], 1)

    for c in (*_FORCE, *_MOMENT, *cov_names):
        if c in cols and np.any(np.isnan(cols[c])):
            r = int(np.argmax(np.isnan(cols[c]))) + 1
            raise RecordingsError(f"{path}: column '{c}' has an empty cell (data row {r} "
                                  f"among the kept rows); fill it or drop the row")
    tens = block(t_cols, np.nan)
    mask = ~np.isnan(tens)
    pose = block((*_POS, *_ROT))
    if kind == "csjm":
        pose[:, :3] = 0.0
    return Recordings(
        l0=block(l0_cols) if kind == "cdpr" else np.zeros((n, m)),
        wrench=block((*_FORCE, *_MOMENT)),
        pose=pose,
        tensions=np.where(mask, tens, 0.0),
        tension_mask=mask,
        moment=block(_CSJM_MOMENT),
        time=block(("time",), np.nan)[:, 0],
        covariates=block(cov_names) if cov_names else np.zeros((n, 0)),
        covariate_names=cov_names,
        kind=kind,
        source=str(path),
        dropped_rows=tuple(dropped),
    )
