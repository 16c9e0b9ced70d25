"""``pairs``: choose the stereo pairs of a block worth matching.

* :mod:`~demtool.pairs.core` — :func:`select_pairs` on the geometry
  :func:`demtool.camera.info.camera_info` measures (overlap, convergence, B/H, sun).
* :mod:`~demtool.pairs.params` — :class:`PairsParams`.
* :mod:`~demtool.pairs.run` — :func:`run_pairs`: sensor models in, a pair list out.
"""
