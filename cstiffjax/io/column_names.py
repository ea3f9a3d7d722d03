"""Header names that look like a contract column but are not one (formats.md §2): a
misspelling (``swivle_2``), a long form (``tension_2`` for ``t_2``, ``length_1`` for
``l0_1``) or a per-cable group with a hole (``swivel_1, swivel_3, swivel_4`` without
``swivel_2``). Unchecked, such a column silently becomes a covariate while the column it
meant goes missing.

A name starting with :data:`COVARIATE_PREFIX` is declared a covariate and never judged.
Names are compared after lower-casing and removing separators (``" _.-"``); a word of
at least :data:`FUZZY_FROM` letters matches within one edit (a letter inserted, dropped,
changed, or two neighbours swapped); shorter words only exactly or through :data:`ALIASES`.
"""

import re

from cstiffjax.io import schema

COVARIATE_PREFIX = "cov_"
"""A header name starting with this is a covariate by declaration (``cov_tension_2``): no
near-miss check applies to it, and it keeps its whole name."""

FUZZY_FROM = 4
"""Words of at least this many letters match a contract word within one edit; shorter ones
(``x``, ``fz``, ``yaw``, ``l0``, ``t``) only exactly (``temp`` is not ``time``'s typo...
but ``tiem`` is)."""

ALIASES = {
    "l0": ("l", "lo", "len", "length", "lengths", "cablelength", "unstrainedlength", "restlength"),
    "t": ("tension", "tensions", "cabletension", "loadcell"),
    "swivel": ("swivelangle", "swiv", "pulleyangle", "swivelencoder"),
    "t_set": ("tset", "tensionset", "setpoint", "tsetpoint", "tensionsetpoint"),
    "time": ("timestamp",),
    "session": ("sessionid",),
}
"""Long forms and other spellings of the contract's words (separators removed, lower case).
A per-cable word must be followed by a cable index to be judged (``tension`` alone is no
near-miss)."""

_INDEXED = re.compile(r"([a-z](?:[a-z _.\-]*[a-z])?)[ _.\-]*([0-9]+)")


def _canon(name: str) -> str:
    return re.sub(r"[ _.\-]", "", name.lower())


def edits(a: str, b: str) -> int:
    """Optimal-string-alignment distance between ``a`` and ``b``: the fewest insertions,
    deletions, substitutions and swaps of two neighbouring letters that turn one into the other."""
    d = [[i + j if i * j == 0 else 0 for j in range(len(b) + 1)] for i in range(len(a) + 1)]
    for i in range(1, len(a) + 1):
        for j in range(1, len(b) + 1):
            d[i][j] = min(d[i - 1][j] + 1, d[i][j - 1] + 1, d[i - 1][j - 1] + (a[i - 1] != b[j - 1]))
            if i > 1 and j > 1 and a[i - 1] == b[j - 2] and a[i - 2] == b[j - 1]:
                d[i][j] = min(d[i][j], d[i - 2][j - 2] + 1)
    return d[len(a)][len(b)]


def _matches(word: str, target: str) -> bool:
    """Whether ``word`` (canonical) is ``target``'s word, an alias of it, or within one edit of
    either (words of :data:`FUZZY_FROM` letters or more)."""
    for w in (_canon(target), *ALIASES.get(target, ())):
        if word == w or (len(w) >= FUZZY_FROM and edits(word, w) <= 1):
            return True
    return False


def meant(name: str, m: int) -> str | None:
    """The contract column that the header name ``name`` most likely means (``None``: none,
    or ``name`` is a contract column or a declared covariate). A per-cable word keeps its
    index (``tension_7`` on a 6-cable robot means ``t_7``, itself out of range)."""
    if name.startswith(COVARIATE_PREFIX) or schema.find(name, m) is not None:
        return None
    low = name.lower()
    if mt := _INDEXED.fullmatch(low):
        word, idx = _canon(mt.group(1)), int(mt.group(2))
        for prefix in (*schema.cable_prefixes(), "t_set"):
            if _matches(word, prefix):
                return None if low == f"{prefix}_{idx}" else f"{prefix}_{idx}"
    word = _canon(low)
    return next((n for n in schema.fixed_names() if word != n and _matches(word, n)), None)


def holes(header, m: int) -> list[tuple[str, list[str], list[str]]]:
    """The per-cable measurement groups (tensions, swivel angles) with a hole:
    ``(quantity, present columns, missing columns)`` where a cable's column is missing
    between two present ones (``swivel_1, swivel_3`` without ``swivel_2``)."""
    present, out = set(header), []
    for g in schema.GROUPS:
        if g.per_cable and g.empty_ok:
            have = [i for i, c in enumerate(g.columns(m), 1) if c in present]
            gaps = [schema.cable_column(g.prefix, i) for i in range(min(have, default=1), max(have, default=0) + 1)
                    if i not in have]
            if gaps:
                out.append((g.quantity, [schema.cable_column(g.prefix, i) for i in have], gaps))
    return out


__all__ = ["ALIASES", "COVARIATE_PREFIX", "edits", "holes", "meant"]
