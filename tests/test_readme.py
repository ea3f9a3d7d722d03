"""The README's quick tour runs as written, on the public API only, and says what it claims."""

import re
from pathlib import Path

import numpy as np
import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def _quick_tour() -> str:
    match = re.search(r"## Quick tour\n\n```python\n(.*?)```", README.read_text(), re.S)
    assert match, "README.md has no '## Quick tour' python block"
    return match.group(1)


def test_quick_tour_uses_only_the_public_api():
    """Every ``cj.X`` and ``fitting.X`` the tour uses is a curated top-level name."""
    import cstiffjax
    import fitting

    code = _quick_tour()
    for prefix, module in (("cj", cstiffjax), ("fitting", fitting)):
        used = set(re.findall(rf"\b{prefix}\.(\w+)", code))
        assert used and used <= set(dir(module)), sorted(used - set(dir(module)))


@pytest.mark.slow
def test_quick_tour_runs_and_its_comments_hold(capsys):
    scope: dict = {}
    exec(compile(_quick_tour(), str(README), "exec"), scope)
    K = np.asarray(scope["K"])
    np.testing.assert_allclose(K, K.T, rtol=1e-8, atol=1e-6 * np.abs(K).max())  # gravity alone: symmetric
    assert scope["dpose_dl0"].shape == (6, 6)
    assert scope["ws"].member.shape == (31 * 21 * 26,) and scope["ws"].member.any()
    d = scope["d"]
    assert d.effects == [] and d.explained  # "[] True: example02 is clean"
    assert "[] True" in capsys.readouterr().out
