"""Volumes from pose grids: trapezoid point volumes, exact for the grid box, convergent for a ball.

References are closed forms (box, ball), independent of the grid code."""

import itertools
import json

import numpy as np
import pytest

from cstiffjax.commands.cli import main
from cstiffjax.workspace.sweep import Grid, sweep


def _ball(grid, centre, radius):
    """Membership of the grid points in a ball (an independent membership function)."""
    P = grid.poses()[:, :3]
    return (np.sum((P - np.asarray(centre)) ** 2, axis=1) <= radius**2).reshape(grid.shape)


def test_box_fully_inside_has_exactly_the_box_volume():
    for n in (2, 3, 5, 11):
        g = Grid.regular((-0.6, 0.6, n), (-0.4, 0.4, n + 1), (0.2, 1.25, n + 2))
        box = 1.2 * 0.8 * 1.05  # = 1.008 m³
        assert g.volume(np.ones(g.shape, bool)) == pytest.approx(box, rel=1e-12)
        assert g.point_volumes().sum() == pytest.approx(box, rel=1e-12)
        # the old estimate, members x interior cell, overshoots by prod(n/(n-1))
        assert len(g) * g.cell_volume > 1.1 * box
    # the 5-point grid of a 2.016 m³ box: 3.94 m³ counted as 125 interior cells, 2.016 m³ now
    g = Grid.regular((-0.6, 0.6, 5), (-0.4, 0.4, 5), (0.0, 2.1, 5))
    assert 125 * g.cell_volume == pytest.approx(3.9375)
    assert g.volume(np.ones(125, bool)) == pytest.approx(2.016, rel=1e-12)


def test_point_volumes_are_half_cells_on_faces_quarter_on_edges_eighth_on_corners():
    g = Grid.regular((0.0, 1.0, 3), (0.0, 2.0, 3), (0.0, 3.0, 4))
    w = g.point_volumes()
    cell = 0.5 * 1.0 * 1.0
    assert w[1, 1, 1] == pytest.approx(cell)
    assert w[0, 1, 1] == pytest.approx(cell / 2) and w[0, 0, 1] == pytest.approx(cell / 4)
    assert w[0, 0, 0] == pytest.approx(cell / 8) and w[2, 2, 3] == pytest.approx(cell / 8)
    flat = Grid.regular((0.0, 1.0, 3), (0.0, 2.0, 5), (0.5, 0.5, 1))  # a section: an area, m²
    assert flat.volume(np.ones(flat.shape, bool)) == pytest.approx(2.0)
    with pytest.raises(ValueError, match="member has 4 entries, the grid 15 points"):
        flat.volume(np.ones(4, bool))


def test_ball_volume_converges_and_its_error_decreases_with_refinement():
    """Lattice-point counts of a ball fluctuate with its offset to the grid: the mean error
    over six offsets must shrink at every refinement, each error stay inside the shell bound."""
    radius = 0.3
    exact = 4.0 / 3.0 * np.pi * radius**3
    centres = np.random.default_rng(0).uniform(-0.03, 0.03, (6, 3))
    mean_errors = []
    for n in (11, 21, 41, 81):
        g = Grid.regular((-0.4, 0.4, n), (-0.4, 0.4, n), (-0.4, 0.4, n))
        h = 0.8 / (n - 1)
        errs = [abs(g.volume(_ball(g, c, radius)) - exact) for c in centres]
        # every miscounted cell lies within one cell diagonal of the sphere: shell of width 2 sqrt(3) h
        assert max(errs) <= 4 * np.pi * radius**2 * 2 * np.sqrt(3) * h, (n, errs)
        mean_errors.append(np.mean(errs))
    assert all(b < a for a, b in itertools.pairwise(mean_errors)), mean_errors
    assert mean_errors[-1] < 0.001 * exact and mean_errors[-1] < mean_errors[0] / 10, mean_errors


def test_ball_cut_by_the_grid_box_counts_the_box_faces_by_halves():
    """A ball centred on a face of the grid box: the grid sees a half ball."""
    radius, exact = 0.3, 2.0 / 3.0 * np.pi * 0.3**3
    errs = []
    for n in (21, 81):
        g = Grid.regular((-0.4, 0.4, n), (-0.4, 0.4, n), (0.0, 0.4, (n + 1) // 2))
        errs.append(abs(g.volume(_ball(g, (0.0, 0.0, 0.0), radius)) - exact))
    assert errs[1] < 0.01 * exact and errs[1] < errs[0] / 4


def test_point_volume_on_the_device_equals_the_host_weights():
    g = Grid.regular((-0.3, 0.3, 4), (-0.2, 0.2, 3), (0.5, 0.9, 5))
    out = sweep(lambda p: g.point_volume(p[:3]), g, chunk_size=16, progress=False)
    np.testing.assert_allclose(out.reshape(g.shape), g.point_volumes(), rtol=1e-14)
    batch = np.asarray(g.point_volume(g.poses().T[:3]))  # pose-minor (3, b)
    np.testing.assert_allclose(batch, g.point_volumes().ravel(), rtol=1e-14)


def test_cli_workspace_of_a_grid_inside_the_workspace_is_the_grid_box(tmp_path):
    """Every pose of a small box around the centre of the TCPR-8 frame is wrench-closure."""
    out = tmp_path / "ws"
    assert main(["workspace", "tcpr8.toml", "--kind", "wrench-closure", "--pose-grid", "-0.1", "0.1", "3",
                 "-0.05", "0.05", "3", "0.7", "0.9", "3", "--no-progress", "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["members"] == 27
    assert summary["volume_m3"] == pytest.approx(0.2 * 0.1 * 0.2, rel=1e-12)  # not 27 cells = 3.375x


def test_css_summary_weights_volume_and_stability_by_point_volume():
    import jax.numpy as jnp

    from cstiffjax.stiffness import css

    s = css.summarize(jnp.array([True, False, True]), jnp.array([0.2, 5.0, 0.4]), jnp.array([1.0, 2.0, 3.0]))
    assert int(s.count) == 2 and float(s.volume) == pytest.approx(4.0)
    assert float(s.stability) == pytest.approx((0.2 * 1 + 0.4 * 3) / 4)  # U = ∫μ dv / ∫dv
