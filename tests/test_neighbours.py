"""The compiled spatial queries behind next-event targets (:mod:`kernel.neighbours`) against brute force."""
import numpy as np

from lpy_light.kernel.neighbours import near_pairs, nearest_other


def test_near_pairs_are_exactly_the_boxes_within_each_radius():
    """Every (triangle, target) whose bounding box comes within the target's radius, none other, in target
    order: with boxes wider than a cell, and far more pairs than the output first holds (it grows)."""
    rng = np.random.default_rng(5)
    lo = rng.random((3000, 3)) * 10.0
    hi = lo + rng.random((3000, 3)) * np.where(rng.random((3000, 1)) < 0.02, 4.0, 0.2)
    center, radius = rng.random((60, 3)) * 10.0, rng.random(60) * 3.0
    targets = np.array(sorted(rng.choice(60, 40, replace=False)))
    tri, t = near_pairs(lo, hi, center, radius, targets)
    gap = np.clip(center[targets][:, None, :], lo[None], hi[None]) - center[targets][:, None, :]
    near = (gap ** 2).sum(axis=2) < radius[targets][:, None] ** 2          # (targets, triangles)
    expected = {(int(i), int(targets[a])) for a, i in zip(*np.nonzero(near))}
    assert len(tri) > 16 + 4 * len(targets)                                    # the output grew
    assert set(zip(tri.tolist(), t.tolist())) == expected and len(tri) == len(expected)
    assert np.all(np.diff(np.searchsorted(targets, t)) >= 0)                   # in target order


def test_near_pairs_with_wide_boxes_and_a_scene_too_wide_for_the_grid():
    """Boxes spanning many cells (walls: tested against every target) and one triangle so far away that the
    grid's cells must grow to stay within MAX_CELLS: still exactly the brute-force pairs."""
    rng = np.random.default_rng(7)
    lo = rng.random((2000, 3)) * 10.0
    hi = lo + rng.random((2000, 3)) * 0.3
    lo[:5], hi[:5] = -50.0, 50.0                                 # five room-sized boxes
    lo[5], hi[5] = (1e7, 1e7, 1e7), (1e7 + 0.1, 1e7 + 0.1, 1e7 + 0.1)    # one far away
    center, radius = rng.random((100, 3)) * 10.0, rng.random(100) * 0.5 + 0.05
    targets = np.arange(100)
    tri, t = near_pairs(lo, hi, center, radius, targets)
    gap = np.clip(center[:, None, :], lo[None], hi[None]) - center[:, None, :]
    near = (gap ** 2).sum(axis=2) < radius[:, None] ** 2
    expected = {(int(i), int(a)) for a, i in zip(*np.nonzero(near))}
    assert set(zip(tri.tolist(), t.tolist())) == expected and len(tri) == len(expected)
    assert {0, 1, 2, 3, 4} <= set(tri.tolist())


def test_nearest_other_target():
    rng = np.random.default_rng(6)
    center = rng.random((50, 3))
    d = np.linalg.norm(center[:, None] - center[None], axis=2)
    np.fill_diagonal(d, np.inf)
    targets = np.array([0, 7, 49])
    assert np.allclose(nearest_other(center, targets), d[targets].min(axis=1), rtol=1e-12)
