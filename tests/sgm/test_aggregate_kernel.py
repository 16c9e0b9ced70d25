"""The vectorised SGM aggregation (explicit 16-lane path updates, issue 28) against a
plain, slow implementation of Hirschmüller (2008) eq. 13–14 on small volumes whose
disparity count spans whole vectors and a remainder."""

import numpy as np
import pytest

from demtool.sgm.aggregate import adapted_p2_table, aggregate_costs

P1, P2 = 3, 20


def reference_path(cost, guide, p2_of_step, dy, dx):
    """L_r of one direction (dy, dx), eq. 13, by plain loops (int64, no sentinels)."""
    height, width, _ = cost.shape
    out = np.zeros(cost.shape, dtype=np.int64)
    rows = range(height) if dy >= 0 else range(height - 1, -1, -1)
    cols = list(range(width)) if dx >= 0 else list(range(width - 1, -1, -1))
    for y in rows:
        for x in cols:
            yp, xp = y - dy, x - dx
            if not (0 <= yp < height and 0 <= xp < width):
                out[y, x] = cost[y, x]  # the path starts here
                continue
            prev = out[yp, xp]
            low = prev.min()
            p2 = p2_of_step[abs(int(guide[y, x]) - int(guide[yp, xp]))]
            for k in range(cost.shape[2]):
                step = min(prev[k - 1] if k > 0 else 10**9,
                           prev[k + 1] if k + 1 < cost.shape[2] else 10**9) + P1
                out[y, x, k] = cost[y, x, k] + min(prev[k], step, low + p2) - low
    return out


def reference_sum(cost, guide, paths, kappa):
    """S = Σ_r L_r (eq. 14) over the 8 or 16 directions."""
    p2_of_step = adapted_p2_table(P1, P2, kappa)
    directions = [(0, 1), (1, 0), (1, 1), (1, -1)]
    if paths == 16:
        directions += [(1, 2), (1, -2), (2, 1), (2, -1)]
    directions += [(-dy, -dx) for dy, dx in directions]
    return sum(reference_path(cost, guide, p2_of_step, dy, dx) for dy, dx in directions)


@pytest.mark.parametrize("n_disp", [16, 37])
@pytest.mark.parametrize("paths,kappa", [(8, 0), (8, 8), (16, 8)])
def test_vectorised_aggregation_equals_the_plain_recursion(n_disp, paths, kappa):
    rng = np.random.default_rng(7)
    cost = rng.integers(0, 60, size=(5, 7, n_disp)).astype(np.uint16)
    cost[2, 3, 20 % n_disp] = 0  # a sharp minimum that the P1/P2 terms spread
    guide = rng.integers(0, 40, size=cost.shape[:2]).astype(np.uint8)
    total = aggregate_costs(cost, p1=P1, p2=P2, paths=paths, guide=guide, p2_kappa=kappa)
    expected = reference_sum(cost, guide, paths, kappa)
    assert total.dtype == np.uint16
    assert np.array_equal(total, expected)
