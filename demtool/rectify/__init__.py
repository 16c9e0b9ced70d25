"""The ``rectify`` stage: a stereo pair resampled so that its epipolar lines are rows.

:mod:`~demtool.rectify.params` (``RectifyParams``), :mod:`~demtool.rectify.core`
(uncalibrated rectification from matches: the homographies, the disparity range),
:mod:`~demtool.rectify.calibrated` (rectification from two sensor models),
:mod:`~demtool.rectify.checks` (checks of a pair before and after rectifying),
:mod:`~demtool.rectify.run` and :mod:`~demtool.rectify.run_sensors` (the runners, from
matches and from sensor models).  The command is :mod:`demtool.commands.rectify`.
"""
