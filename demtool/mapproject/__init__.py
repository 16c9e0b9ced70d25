"""The ``mapproject`` stage: raw images onto a body's map through their sensor models.

:mod:`~demtool.mapproject.params` (``MapprojectParams``), :mod:`~demtool.mapproject.core`
(the ortho grid and the projection of map cells into the raw image),
:mod:`~demtool.mapproject.sampling` (resampling the raw image at those pixels),
:mod:`~demtool.mapproject.stereo` (map-projected stereo: the orthos' search range, map
cells back to raw pixels; used by ``sgm``, ``match`` and ``dem --mapprojected``),
:mod:`~demtool.mapproject.run` (``run_mapproject``) and :mod:`~demtool.mapproject.tiled`
(the tiled job).  The command is :mod:`demtool.commands.mapproject`.
"""
