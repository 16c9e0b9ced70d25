"""The ``select`` stage: which images of a set to give the bundle adjustment.

:mod:`~demtool.select.params` (``SelectParams``), :mod:`~demtool.select.core` (the pure
core: matches, overlap and geometry scores against the target image) and
:mod:`~demtool.select.run` (``run_select``: files in, ``selection.json`` out).  The
command is :mod:`demtool.commands.select`.
"""
