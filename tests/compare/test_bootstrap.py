"""The block bootstrap of the alignment's sigmas (demtool.compare.coreg._bootstrap_sigma)."""

import numpy as np

from demtool.compare.coreg import _block_ids, _bootstrap_sigma


def bincount_sigma(design, target, blocks, *, replicates=300, seed=0):
    """The formulation before the compiled block sums: np.unique and 12 np.bincount."""
    ids, inverse = np.unique(blocks, return_inverse=True)
    n_params = design.shape[1]
    if ids.size < 8:
        return np.full(n_params, np.nan)
    outer = design[:, :, None] * design[:, None, :]
    normal = np.stack([np.bincount(inverse, weights=outer[:, i, j], minlength=ids.size)
                       for i in range(n_params) for j in range(n_params)], axis=1)
    rhs = np.stack([np.bincount(inverse, weights=design[:, i] * target, minlength=ids.size)
                    for i in range(n_params)], axis=1)
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, ids.size, size=(replicates, ids.size))
    weights = np.zeros((replicates, ids.size))
    np.add.at(weights, (np.repeat(np.arange(replicates), ids.size), draws.ravel()), 1.0)
    sums = (weights @ normal).reshape(replicates, n_params, n_params)
    solutions = np.linalg.solve(sums, (weights @ rhs)[..., None])[..., 0]
    return solutions.std(axis=0, ddof=1)


def test_equal_to_the_bincount_formulation_bit_for_bit():
    rng = np.random.default_rng(0)
    for shape, n_params in (((120, 90), 3), ((64, 64), 7), ((300, 41), 3)):
        blocks = _block_ids(shape).ravel()
        keep = rng.random(blocks.size) > 0.3  # some blocks thinned, ids not contiguous
        keep[blocks % 5 == 2] = False  # whole blocks missing
        design = rng.normal(size=(int(keep.sum()), n_params))
        target = design @ rng.normal(size=n_params) + rng.normal(size=len(design)) * 0.1
        for seed in (0, 4):
            found = _bootstrap_sigma(design, target, blocks[keep], seed=seed)
            assert np.array_equal(found, bincount_sigma(design, target, blocks[keep],
                                                        seed=seed))
            assert np.all(found > 0)


def test_too_few_blocks_give_nan():
    design = np.ones((50, 3))
    assert np.isnan(_bootstrap_sigma(design, np.ones(50), np.arange(50) % 7)).all()
