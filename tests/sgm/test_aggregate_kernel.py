"""The vectorised SGM aggregation (explicit 16-lane path updates over whole rows, issue
28) against a plain, slow implementation of Hirschmüller (2008) eq. 13–14 on small
volumes whose disparity count is below one vector (the scalar kernel), one vector, and
whole vectors and a remainder (the overlapping last vector)."""

import numpy as np
import pytest

from demtool.sgm.aggregate import aggregate_costs
from tests.helpers.sgm import reference_aggregation

P1, P2 = 3, 20


@pytest.mark.parametrize("n_disp", [5, 16, 37])
@pytest.mark.parametrize("paths,kappa", [(8, 0), (8, 8), (16, 8)])
def test_vectorised_aggregation_equals_the_plain_recursion(n_disp, paths, kappa):
    rng = np.random.default_rng(7)
    cost = rng.integers(0, 60, size=(5, 7, n_disp)).astype(np.uint16)
    cost[2, 3, 20 % n_disp] = 0  # a sharp minimum that the P1/P2 terms spread
    guide = rng.integers(0, 40, size=cost.shape[:2]).astype(np.uint8)
    total = aggregate_costs(cost, p1=P1, p2=P2, paths=paths, guide=guide, p2_kappa=kappa)
    expected = reference_aggregation(cost, guide, paths, kappa, P1, P2)
    assert total.dtype == np.uint16
    assert np.array_equal(total, expected)
