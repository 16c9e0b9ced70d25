"""Cells a sensor sees on a map grid (demtool.dem.overlap), against projecting every cell."""

import logging

import numpy as np
import pytest

from demtool.dem.overlap import LATTICE_STEP, cells_seen, inside_image
from demtool.maps import body_by_name
from demtool.maps.grids import grid_from_xyz, grid_xyz
from tests.helpers.frame_scene import make_frame_scene
from tests.helpers.linescan import linescan_sensor

MOON = body_by_name("Moon")


def every_cell(model, grid, height):
    """The reference: one ground-to-image projection per cell."""
    return inside_image(model, *model.ground_to_image(grid_xyz(grid, height)))


def footprint_grid(model, gsd, *, pad=0.3):
    """A map grid around the image's footprint, ``pad`` of its size wider on each side."""
    lines = np.array([0.5, 0.5, model.lines - 0.5, model.lines - 0.5])
    samples = np.array([0.5, model.samples - 0.5, 0.5, model.samples - 0.5])
    corners = model.image_to_ground(lines, samples)
    centre = corners.mean(axis=0)
    return grid_from_xyz(MOON, centre + (1 + 2 * pad) * (corners - centre), gsd)


@pytest.mark.parametrize("roll", [0.0, 25.0])
@pytest.mark.parametrize("gsd", [1.0, 3.0])
def test_line_scan_equals_every_cell(roll, gsd):
    model = linescan_sensor(lines=400, samples=300, gsd=1.0, roll_deg=roll)
    grid = footprint_grid(model, gsd)
    assert min(grid.shape) >= 4 * LATTICE_STEP  # many lattice squares, edges inside them
    for height in (0.0, 350.0):
        expected = every_cell(model, grid, height)
        assert 0.2 < expected.mean() < 0.9  # edges inside the grid
        assert np.array_equal(cells_seen(model, grid, height), expected)


def test_frame_pair_equals_every_cell():
    scene = make_frame_scene(size=160, seed=3)
    for model in (scene.left, scene.right):
        grid = footprint_grid(model, 5.0)  # the scene's GSD
        expected = every_cell(model, grid, 0.0)
        assert np.array_equal(cells_seen(model, grid, 0.0), expected)
        assert np.array_equal(cells_seen(model, grid, 0.0, step=5, margin_px=0.5), expected)


def test_small_grids_equal_every_cell():
    model = linescan_sensor(lines=40, samples=30, gsd=1.0)
    grid = footprint_grid(model, 1.0)
    assert min(grid.shape) < 4 * LATTICE_STEP
    assert np.array_equal(cells_seen(model, grid, 0.0), every_cell(model, grid, 0.0))


class Wavy:
    """A sensor whose image position bends within a lattice square (bilinear is off)."""

    lines, samples = 400.0, 400.0

    def __init__(self, model, amplitude_px):
        self.model, self.amplitude = model, amplitude_px

    def ground_to_image(self, xyz):
        line, sample = self.model.ground_to_image(xyz)
        return line + self.amplitude * np.sin(sample / 3.0), sample


def test_a_bending_mapping_refines_the_lattice(caplog):
    model = Wavy(linescan_sensor(lines=400, samples=400, gsd=1.0), amplitude_px=6.0)
    grid = footprint_grid(model.model, 1.0)
    with caplog.at_level(logging.DEBUG, logger="demtool.mapproject.core"):
        found = cells_seen(model, grid, 0.0)
    assert "refining" in caplog.text  # the lattice was found off, not used as it was
    assert np.array_equal(found, every_cell(model, grid, 0.0))
    caplog.clear()
    with caplog.at_level(logging.DEBUG, logger="demtool.mapproject.core"):
        cells_seen(model.model, grid, 0.0)
    assert "refining" not in caplog.text  # the straight sensor uses the first lattice
