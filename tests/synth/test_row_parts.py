"""The synth kernels over row parts on threads give the one-thread result to the bit."""

from __future__ import annotations

import numpy as np

from demtool.synth import SceneParams, make_scene, render
from demtool.synth.body import placement, surface_height
from tests.helpers.row_parts import whole_and_split
from tests.synth.test_body import plane_field


def _assert_parts_and_identical(whole, split, seen):
    assert any(len(parts) > 1 for parts in seen)  # the kernels did run in parts
    for a, b in zip(whole, split, strict=True):
        np.testing.assert_array_equal(a, b)


def test_rendered_views_in_parts_are_the_one_thread_views(monkeypatch):
    params = SceneParams(dem_size=96, n_views=2, image_size=128, crater_count=8,
                         crater_max_diameter_m=20.0, boulder_count=20)

    def compute():
        scene = make_scene(params)
        return [a for name in scene.names
                for a in (scene.images[name], scene.depths[name], scene.shadows[name])]

    whole, split, seen = whole_and_split(monkeypatch, compute, parts=2)
    assert np.isfinite(whole[1]).all() and whole[2].any()  # hits everywhere, some shadow
    _assert_parts_and_identical(whole, split, seen)


def test_rays_and_radial_heights_in_parts_are_the_one_thread_values(monkeypatch):
    field = plane_field(a=0.05, b=-0.02, c=3.0)
    rng = np.random.default_rng(2)
    origins = np.column_stack([rng.uniform(-150, 150, (400, 2)), np.full(400, 500.0)])
    directions = np.column_stack([rng.uniform(-0.3, 0.3, (400, 2)), -np.ones(400)])
    place = placement("Moon", 10.0, 20.0)
    lon = 10.0 + rng.uniform(-0.004, 0.004, 400)
    lat = 20.0 + rng.uniform(-0.004, 0.004, 400)

    def compute():
        return (render.intersect_rays(field, origins, directions),
                surface_height(place, field, lon, lat))

    whole, split, seen = whole_and_split(monkeypatch, compute)
    assert np.isfinite(whole[0]).mean() > 0.8 and np.isfinite(whole[1]).mean() > 0.8
    _assert_parts_and_identical(whole, split, seen)


def test_a_zero_direction_is_a_miss_not_an_error():
    # the row kernels keep the parfor loops' numpy error model (no ZeroDivisionError)
    field = plane_field()
    hits = render.intersect_rays(field, np.array([[0.0, 0.0, 100.0]] * 2),
                                 np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -1.0]]))
    assert np.isnan(hits[0]).all() and np.allclose(hits[1], [0.0, 0.0, 0.0])
