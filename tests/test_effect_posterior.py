"""The posterior check's per-effect summary (fitting.diagnosis.effect_posterior._block_summary) on a
chain whose distribution is known: independent unit normals, so the Mahalanobis² of the
null is chi-square distributed and its tail has a closed form (2 dof: exp(-d²/2))."""

from types import SimpleNamespace

import numpy as np
from scipy import stats

from fitting.diagnosis.effect_posterior import WALD_P, _block_summary

# θ layout of a small model: 2 EA log-scales, effect "a" (block "x", 2 entries), effect "b"
# (scalar "y"). EA 2 is frozen, so the chain's columns are θ entries 0, 2, 3, 4.
MODEL = SimpleNamespace(
    effects=(SimpleNamespace(name="a"), SimpleNamespace(name="b")),
    blocks=((0, "x", 2, (2,), "m"), (1, "y", 4, (), "N")),
    null=np.array([0.0, 0.0, 0.5, -0.5, 3.0]),
    scale=np.array([1.0, 1.0, 2.0, 2.0, 0.1]),
    block_slice=lambda i: slice(2, 4) if i == 0 else slice(4, 5),
    effect_index=lambda name: "ab".index(name),
)
FREE = np.array([0, 2, 3, 4])
TAIL_A = 0.01  # effect a: the null at Mahalanobis² 2 ln(100), tail 1e-2 > WALD_P: not confirmed
MEAN = np.array([5.0, *(np.full(2, np.sqrt(np.log(1 / TAIL_A)))), 5.0])  # θ units (unit posterior std)


def _chain(n=200_000, seed=0):
    return MEAN + np.random.default_rng(seed).standard_normal((n, 4))


def test_block_summary_against_the_chi_square_tail():
    chain = _chain()
    a, b = (_block_summary(chain, MODEL, FREE, name) for name in ("a", "b"))
    # the tail of the null: closed form for 2 dof, binomial spread ~2e-4 at 2e5 samples
    assert abs(a["null_tail"] - TAIL_A) < 1e-3
    assert abs(a["null_d2"] - 2 * np.log(1 / TAIL_A)) < 0.05
    assert not a["agrees"]  # 1e-2 is not below WALD_P = 1e-3
    assert b["null_tail"] < 1e-4 and b["agrees"]  # 5 sigma, 1 dof: tail 5.7e-7
    assert stats.chi2.sf(b["null_d2"], 1) < WALD_P
    # physical units: value = null + scale θ; the 90% interval is ±1.645 scale around the median
    x, y = a["parameters"]["x"], b["parameters"]["y"]
    np.testing.assert_allclose(x["median"], MODEL.null[2:4] + 2.0 * MEAN[1:3], atol=0.02)
    np.testing.assert_allclose(np.subtract(x["interval90"][1], x["interval90"][0]), 2 * 1.6449 * 2.0, rtol=0.02)
    np.testing.assert_allclose(x["z_null"], MEAN[1:3], atol=0.02)
    assert x["null_outside_999"] == [False, False]  # |z| 2.15 each: inside the 99.9% interval
    assert isinstance(y["median"], float) and abs(y["median"] - (3.0 + 0.1 * 5.0)) < 0.002
    assert y["null_outside_999"] is True and abs(y["z_null"] - 5.0) < 0.02
    assert x["null"] == [0.5, -0.5] and y["null"] == 3.0
