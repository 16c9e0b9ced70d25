"""The stage registry: every ``demtool`` stage, in pipeline order, with its one-line summary.

A light module (no click, no numpy) shared by the command line (:mod:`demtool.cli`,
which lists the stages and loads ``demtool.commands.<stage>``), the runners
(``demtool.<stage>.run``) and the tests.  A new stage is added here first; see
CONTRIBUTING.md ("Adding a stage").
"""

from __future__ import annotations

# stage name -> one-line description, in pipeline order
STAGES: dict[str, str] = {
    "synth": "Render a synthetic planetary scene: terrain, albedo, cameras, images, truth.",
    "select": "Select the images that overlap a target image (SIFT, ratio test, RANSAC).",
    "bundle": "Bundle adjustment: structure from motion (pycolmap), or sensor models as priors.",
    "rectify": "Rectify a stereo pair: from SIFT matches (RANSAC F, Hartley) or sensor models.",
    "sgm": "Semi-global matching of a rectified or map-projected pair (MI, census).",
    "match": "Area-based matching: seeds, Delaunay, pyramid NCC, least-squares matching.",
    "dem": "Dense DEM from bundle points or a disparity: in the target frame or on the body's map.",
    "refine": "Shape-from-shading refinement of a coarse DEM (lunar-Lambert).",
    "mapproject": "Resample an image onto the body's map through its sensor model (cam2map).",
    "pairs": "Choose the stereo pairs of a block: overlap, convergence and B/H, sun.",
    "fuse": "Fuse DEMs of one area: co-registration, robust weighted combination, blending.",
    "compare": "Measure a DEM against a reference: co-registration, statistics, plots.",
    "camera": "What sensor models see: footprint, GSD, sun and view angles, pair B/H, overlap.",
}

