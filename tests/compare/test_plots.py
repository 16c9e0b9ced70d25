"""The comparison figures draw large grids from every k-th cell (demtool.compare.plots):
the same picture, without contouring and resampling millions of cells."""

from __future__ import annotations

import io

import numpy as np
import pytest

from demtool.compare import plots


def decoded(png: bytes) -> np.ndarray:
    from matplotlib import image

    return image.imread(io.BytesIO(png), format="png")


@pytest.mark.parametrize(("shape", "stride"), [((512, 512), 1), ((1200, 30), 1),
                                               ((1201, 30), 2), ((2048, 2048), 2),
                                               ((5000, 20000), 17)])
def test_stride_keeps_the_longer_side_within_the_display_samples(shape, stride):
    assert plots.display_stride(shape) == stride
    assert -(-max(shape) // stride) <= plots.DISPLAY_SAMPLES


def test_a_strided_map_covers_the_whole_grid():
    plt = plots._pyplot()
    values = np.arange(2500 * 90, dtype=float).reshape(2500, 90)
    figure, axis = plt.subplots()
    image = plots._map_image(axis, values, (2.0, 0.5), 3, cmap="gray")
    shown = image.get_array()
    assert shown.shape == (834, 30)
    assert shown[1, 1] == values[3, 3]
    # sample i stands for cells 3i … 3i + 2: its extent is 3 cells a sample
    assert image.get_extent() == [0.0, 30 * 3 * 2.0, 834 * 3 * 0.5, 0.0]
    assert axis.get_xlim() == (0.0, 90 * 2.0)
    assert axis.get_ylim() == (2500 * 0.5, 0.0)
    plt.close(figure)


def smooth_field(size: int) -> np.ndarray:
    y, x = np.mgrid[0:size, 0:size] / size
    field = 10.0 * np.sin(6.0 * x) * np.cos(5.0 * y)
    field[: size // 10, : size // 8] = np.nan  # a hole
    return field


def changed_pixels(picture: np.ndarray, other: np.ndarray) -> float:
    """The share of ``picture``'s pixels of which no pixel of ``other`` at most one pixel
    away has all channels within 0.1: what moved by more than a pixel, or changed."""
    padded = np.pad(other, ((1, 1), (1, 1), (0, 0)), mode="edge")
    height, width = picture.shape[:2]
    nearest = np.full((height, width), np.inf)
    for dy in range(3):
        for dx in range(3):
            moved = padded[dy:dy + height, dx:dx + width]
            nearest = np.minimum(nearest, np.abs(picture - moved).max(axis=-1))
    return float((nearest > 0.1).mean())


def test_a_strided_figure_looks_like_the_full_one(monkeypatch):
    """1300² cells, drawn from every second cell (contours traced on every third) and
    from all: the decoded pictures differ on few pixels (the hole's edge and contour
    lines shifted by a cell): under 1 % of them by more than a pixel."""
    field = smooth_field(1300)
    reference = field + 0.3 * np.cos(20.0 * np.linspace(0, 1, 1300))[None, :]
    spacing = (0.5, 0.5)

    def figures() -> list[np.ndarray]:
        return [decoded(plots.difference_figure(field - reference, spacing, title="t")),
                decoded(plots.dems_figure([("dem", field), ("reference", reference)],
                                          spacing)),
                decoded(plots.completeness_figure(np.isfinite(field), spacing,
                                                  percent=99.0))]

    strided = figures()
    assert plots.display_stride(field.shape) == 2
    assert plots.display_stride(field.shape, plots.CONTOUR_SAMPLES) == 3
    monkeypatch.setattr(plots, "DISPLAY_SAMPLES", 10**6)
    monkeypatch.setattr(plots, "CONTOUR_SAMPLES", 10**6)
    full = figures()
    for fast, slow in zip(strided, full, strict=True):
        assert fast.shape == slow.shape
        assert changed_pixels(fast, slow) < 0.01 and changed_pixels(slow, fast) < 0.01


def test_fixed_margins_keep_every_label_inside_the_figure(monkeypatch):
    """The figures are laid out with fixed margins (no layout engine): every title, tick
    label, axis label and legend lies inside the picture, and no panel's labels reach
    into a neighbouring panel."""
    drawn = []
    monkeypatch.setattr(plots, "_png", lambda figure: drawn.append(figure) or b"")
    field = smooth_field(300) * 100.0 - 1500.0  # heights of four digits and a sign
    reference = field + 0.5
    spacing = (2.0, 2.0)
    stats = {"rmse": 0.123, "nmad": 0.1, "mean": -0.000287, "median": 0.0, "count": 81000,
             "le90": 0.2}
    plots.difference_figure(field - reference, spacing, title="dem_linescan_refined − ref",
                            stats=stats)
    plots.dems_figure([("dem", field), ("other", field), ("reference", reference)], spacing)
    plots.profiles_figure([("reference", reference), ("dem", field)],
                          plots.default_profiles(field.shape), spacing)
    plots.histogram_figure(field - reference + np.random.default_rng(0).normal(
        0, 0.1, field.shape), stats=stats, title="dem − reference")
    plots.completeness_figure(np.isfinite(field), spacing, percent=95.0, title="dem")
    frequency = np.geomspace(1e-3, 0.25, 50)
    plots.coherence_figure(frequency, np.linspace(1, 0, 50), cutoff_per_m=0.05, title="dem")
    assert len(drawn) == 6
    for figure in drawn:
        renderer = figure.canvas.get_renderer()
        figure.draw(renderer)
        bounds = figure.bbox
        for axis in figure.axes:  # its drawn ticks, labels, title and legend
            box = axis.get_tightbbox(renderer)
            assert box.x0 >= bounds.x0 - 1 and box.x1 <= bounds.x1 + 1, axis.get_title()
            assert box.y0 >= bounds.y0 - 1 and box.y1 <= bounds.y1 + 1, axis.get_title()
        panels = [a for a in figure.axes if a.get_label() != "<colorbar>"]
        for axis in panels:
            labels = axis.get_tightbbox(renderer)
            for other in panels:
                if other is not axis:
                    assert not labels.overlaps(other.get_window_extent(renderer))


def test_profiles_and_grids_share_one_compiled_sampler():
    """sample_bilinear reads its positions flat: a profile's 1-D positions and a grid's
    2-D ones use one compiled signature (each more costs a fresh clone a compile), with
    the values of the same positions sampled either way."""
    from demtool.compare import grids

    values = smooth_field(40)
    rows, cols = np.meshgrid(np.linspace(2, 30, 7), np.linspace(1, 35, 5), indexing="ij")
    on_grid = grids.sample_bilinear(values, rows, cols)
    along = grids.sample_bilinear(values, rows.ravel(), cols.ravel())
    single = grids.sample_bilinear(values, np.float64(rows[2, 3]), np.float64(cols[2, 3]))
    assert on_grid.shape == rows.shape and along.shape == (rows.size,) and single.shape == ()
    assert np.array_equal(on_grid.ravel(), along, equal_nan=True)
    assert single == on_grid[2, 3]
    assert len(grids._sample_bilinear.signatures) == 1


def test_a_given_limit_is_the_one_each_figure_finds():
    """make_figures computes the |dh| percentile once for the difference map and the
    histogram: the same number, so the same bytes as each finding its own."""
    from demtool.compare.plots import difference_figure, histogram_figure, symmetric_limit

    rng = np.random.default_rng(8)
    difference = rng.normal(scale=0.3, size=(30, 40))
    difference[3:6, 7:9] = np.nan
    stats = {"rmse": 0.3, "nmad": 0.3, "mean": 0.0, "median": 0.0, "count": 1194,
             "le90": 0.5}
    limit = symmetric_limit(difference)
    assert limit == symmetric_limit(difference[np.isfinite(difference)])
    assert difference_figure(difference, (2.0, 2.0), stats=stats, limit=limit) == \
        difference_figure(difference, (2.0, 2.0), stats=stats)
    assert histogram_figure(difference, stats=stats, limit=limit) == \
        histogram_figure(difference, stats=stats)
