"""Registration of every view of a hard block: richer features, and why a view fails.

COLMAP's default SIFT (Lowe 2004, as VLFeat computes it) finds few features on weakly
textured objects (plaster, regolith in shadow) and matches few of them across the
wide angles between the views of a ring (22.5° on Middlebury's templeSparseRing), so
incremental mapping leaves views out.  :data:`RICH_SIFT` is the extraction COLMAP's
documentation recommends for such cases (``colmap feature_extractor`` FAQ,
"Increase number of matches / sparse 3D points"):

* a lower ``peak_threshold`` (a third of the default 0.02/3): features of lower
  contrast, where texture is weak;
* ``estimate_affine_shape``: affine-covariant frames (Mikolajczyk & Schmid 2004), so
  a feature seen 20-40° obliquely from the next view still matches;
* ``domain_size_pooling`` (DSP-SIFT, Dong & Soatto 2015): descriptors pooled over
  scales, more distinctive on smooth surfaces;
* the image doubled first (``first_octave = -1``, COLMAP's default) and five octaves.

Features are extracted up to the object's silhouette: the scratch copies hold the
whole image, no mask drops the edge of a dark background.  Matching then uses guided
matching (matches re-found along the epipolar lines of the verified two-view
geometry), every pair of the block (loop closure around a ring).  Extraction is
about 7× slower (templeSparseRing: 115 s instead of 16 s on a loaded 2-core machine),
so ``features="auto"`` uses it only when the standard features leave views
unregistered.

:func:`unregistered_reasons` tells, per view left out, which step failed: no
features, too few matches, too few verified (inlier) matches with the registered
views, too few 2-D-3-D correspondences for an absolute pose, or a pose that RANSAC
could not find although there were enough correspondences (too few inliers, or a
degenerate configuration).

References
----------
D. G. Lowe, "Distinctive image features from scale-invariant keypoints", IJCV 60(2),
91-110, 2004.
K. Mikolajczyk, C. Schmid, "Scale & affine invariant interest point detectors",
IJCV 60(1), 63-86, 2004.
J. Dong, S. Soatto, "Domain-size pooling in local descriptors: DSP-SIFT", CVPR 2015.
J. L. Schönberger, J.-M. Frahm, "Structure-from-motion revisited", CVPR 2016.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from demtool.bundle.runtime import load_pycolmap

#: ``features`` choices of :class:`demtool.bundle.colmap.SfmOptions`.
FEATURES = ("auto", "standard", "rich")
#: SiftExtractionOptions of the rich extraction (see the module docstring).
RICH_SIFT: dict[str, Any] = {"peak_threshold": 0.02 / 9, "estimate_affine_shape": True,
                             "domain_size_pooling": True, "first_octave": -1,
                             "num_octaves": 5}
#: Fewest features of an image worth matching.
MIN_FEATURES = 15


def sift_options(extraction, rich: bool) -> None:
    """Set the SIFT options of a ``pycolmap.FeatureExtractionOptions`` for ``rich``."""
    if rich:
        for key, value in RICH_SIFT.items():
            setattr(extraction.sift, key, value)


def unregistered_reasons(database_path: str | Path, model, files: Mapping[str, str], *,
                         min_matches: int, min_inliers: int) -> dict[str, dict[str, Any]]:
    """Why each view of the database is not in ``model``.

    Parameters
    ----------
    database_path : path-like
        COLMAP database of the block (features, matches, verified two-view geometries).
    model : pycolmap.Reconstruction or None
        The model kept (None: nothing registered).
    files : mapping of file name to view name
    min_matches : int
        Fewest verified matches of a pair that COLMAP's mapper uses
        (``IncrementalPipelineOptions.min_num_matches``).
    min_inliers : int
        Fewest absolute-pose inliers that register a view
        (``IncrementalMapperOptions.abs_pose_min_num_inliers``).

    Returns
    -------
    dict of view name to dict
        ``reason`` (one line), ``features`` (keypoints), ``matched_views`` (views with
        raw matches), ``verified_views`` (registered views with at least
        ``min_matches`` verified matches), ``verified_matches`` (the most with one
        registered view), ``correspondences_2d3d`` (its features matched to a
        feature of a registered view that has a 3-D point).
    """
    pycolmap = load_pycolmap()
    registered: dict[int, Any] = {}
    if model is not None:
        for image_id in model.reg_image_ids():
            registered[model.image(image_id).name] = model.image(image_id)
    database = pycolmap.Database.open(database_path)
    try:
        images = {image.name: image for image in database.read_all_images()}
        left_out = [f for f in files if f not in registered]
        if not left_out:
            return {}
        by_id = {image.image_id: image.name for image in images.values()}
        pair_ids, geometries = database.read_two_view_geometries()
        verified: dict[tuple[str, str], np.ndarray] = {}
        for pair_id, geometry in zip(pair_ids, geometries, strict=True):
            a, b = pycolmap.pair_id_to_image_pair(pair_id)
            verified[(by_id[a], by_id[b])] = np.asarray(geometry.inlier_matches)
        raw_pairs = set()
        for pair_id, matches in zip(*database.read_all_matches(), strict=True):
            if len(matches):
                a, b = pycolmap.pair_id_to_image_pair(pair_id)
                raw_pairs.add((by_id[a], by_id[b]))
        reasons = {}
        for file in left_out:
            image = images.get(file)
            n_features = database.num_keypoints_for_image(image.image_id) if image else 0
            matched = {b if a == file else a for a, b in raw_pairs if file in (a, b)}
            with_3d: set[int] = set()
            best, views = 0, 0
            for (a, b), inliers in verified.items():
                if file not in (a, b) or len(inliers) == 0:
                    continue
                other, mine, theirs = (b, 0, 1) if a == file else (a, 1, 0)
                if other not in registered:
                    continue
                best = max(best, len(inliers))
                views += len(inliers) >= min_matches
                other_image = registered[other]
                for row in inliers:
                    if other_image.point2D(int(row[theirs])).has_point3D():
                        with_3d.add(int(row[mine]))
            if n_features < MIN_FEATURES:
                reason = f"too few features ({n_features})"
            elif best < min_matches:
                reason = (f"too few verified matches with the registered views (at most "
                          f"{best}, {min_matches} needed; raw matches with {len(matched)} "
                          "view(s))")
            elif len(with_3d) < min_inliers:
                reason = (f"too few 2-D-3-D correspondences ({len(with_3d)}, "
                          f"{min_inliers} needed) for an absolute pose")
            else:
                reason = (f"no absolute pose from {len(with_3d)} 2-D-3-D correspondences "
                          f"(fewer than {min_inliers} RANSAC inliers, or a degenerate "
                          "pose)")
            reasons[files[file]] = {"reason": reason, "features": int(n_features),
                                    "matched_views": len(matched),
                                    "verified_views": int(views),
                                    "verified_matches": int(best),
                                    "correspondences_2d3d": len(with_3d)}
        return reasons
    finally:
        database.close()
