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


def picked_samples_sigma(last, shape, seed):
    """Nuth & Kääb's final bootstrap as it was: the samples picked from the grids,
    stacked into a design matrix ``(∂z/∂x, ∂z/∂y, −1)`` and given to _bootstrap_sigma."""
    dh, gx, gy, params = last["dh"], last["grad_x"], last["grad_y"], last["params"]
    keep = last["usable"] & np.isfinite(dh) & np.isfinite(gx) & np.isfinite(gy)
    if last["halfwidth"] > 0:
        model = params[0] * gx + params[1] * gy - params[2]
        with np.errstate(invalid="ignore"):
            keep &= np.abs(dh - model - last["centre"]) <= last["halfwidth"]
    design = np.column_stack([gx[keep], gy[keep], -np.ones(int(keep.sum()))])
    return _bootstrap_sigma(design, dh[keep], _block_ids(shape)[keep], seed=seed)


def test_final_bootstrap_from_the_grids_is_the_picked_samples_one(monkeypatch):
    """The blocks' normal equations summed straight from the grids (one thread, and the
    even and odd blocks on two): the sigmas of the samples picked and stacked, to the
    bit, with holes, unusable cells, outliers cut at the half-width (or none cut), a
    grid whose blocks do not divide it and blocks left empty."""
    import demtool.compare.threads as compare_threads
    from demtool.compare.coreg import _final_bootstrap

    rng = np.random.default_rng(5)
    for shape, halfwidth in (((130, 97), 0.35), ((64, 80), 0.0), ((41, 300), 0.2)):
        gx, gy = rng.normal(size=shape), rng.normal(size=shape)
        dh = 0.3 * gx - 0.2 * gy + 0.05 + rng.standard_t(2, size=shape) * 0.1
        dh[rng.random(shape) < 0.05] = np.nan
        gx[rng.random(shape) < 0.02] = np.nan
        usable = rng.random(shape) > 0.1
        usable[: shape[0] // 3, : shape[1] // 3] = False  # whole blocks without a sample
        last = {"dh": dh, "grad_x": gx, "grad_y": gy, "usable": usable,
                "params": np.array([0.31, -0.19, -0.04]), "centre": 0.01,
                "halfwidth": halfwidth}
        expected = picked_samples_sigma(last, shape, seed=3)
        assert np.all(np.isfinite(expected) & (expected > 0))
        for cells in (10**9, 1):  # one thread, then two
            monkeypatch.setattr(compare_threads, "THREADED_CELLS", cells)
            monkeypatch.setattr("demtool.tiling.tasks.usable_threads", lambda: 2)
            assert np.array_equal(_final_bootstrap(last, shape, seed=3), expected)
