"""Push-frame camera: usgscsm's ``UsgsAstroPushFrameSensorModel``.

A push-frame image (LRO WAC, Mars Odyssey THEMIS-VIS, JunoCam) is a stack of
*framelets*: each is a short frame exposure of ``framelet_height`` detector lines, taken
every ``interframe_delay`` seconds as the spacecraft moves, each exposure lasting
``exposure_duration`` seconds.  usgscsm's definitions, reproduced here:

- the framelet of image line ``l`` is ``k = ⌊l / h⌋`` with ``h = framelet_height /
  detector_line_summing`` (the summed framelet height); when
  ``framelet_order_reversed`` the framelets were exposed last-first, and ``k`` becomes
  ``n_framelets − k − 1`` for the time;
- its exposure time (seconds from the centre time) is ``starting_ephemeris_time +
  exposure_duration / 2 + k · interframe_delay − center_ephemeris_time``;
- the detector line within the framelet is ``l mod h`` (``h − (l mod h)`` when
  ``framelets_flipped``); with the sample it maps to the focal plane as for a frame
  camera (``focal2pixel``, detector centre, starting line/sample, summing), and the
  look vector is ``(−u, −v, −f)`` rotated by the sensor-to-body quaternion at the
  framelet's time (the pose as the line-scan model's: Lagrange interpolation of the
  resampled ephemeris, usgscsm's ``getAdjSensorPosVel``/``getQuaternions``).

Ground to image is usgscsm's: a secant search over framelet numbers for the framelet
whose centre line sees the point closest to the framelet's middle detector line
(``calcFrameDistance``), then the point projected with that framelet's pose into the
detector, ``line = detector line + k · h``.  Where neighbouring framelets overlap on the
ground a point is seen in both; usgscsm returns the framelet nearest its middle, and so
does this model (after the secant, the framelets on either side are compared).  Light
time and aberration are ignored, as in usgscsm.

Reference: DOI-USGS/usgscsm ``src/UsgsAstroPushFrameSensorModel.cpp`` (``getImageTime``,
``losToEcf``, ``groundToImage``, ``calcFrameDistance``, ``constructStateFromIsd``) and
``tests/PushFrameCameraTests.cpp``.
"""

from __future__ import annotations

import numpy as np

from demtool.sensors.base import Ray
from demtool.sensors.linescan import LineScanSensor


class PushFrameSensor(LineScanSensor):
    """A CSM push-frame camera in a body-fixed frame.

    Parameters
    ----------
    framelet_height : int
        Detector lines per framelet (before summing).
    exposure_duration, interframe_delay : float
        Seconds.
    starting_time : float
        ``starting_ephemeris_time`` of the ISD minus the centre time, seconds.
    framelets_flipped, framelet_order_reversed : bool
        usgscsm's flags (see the module docstring).
    **pose
        The keyword arguments of :class:`LineScanSensor` except ``line_scan_rate``
        (ephemeris, attitude, interior orientation, size, radii, sun).
    """

    kind = "pushframe"

    def __init__(self, *, framelet_height: int, exposure_duration: float,
                 interframe_delay: float, starting_time: float,
                 framelets_flipped: bool = False, framelet_order_reversed: bool = False,
                 **pose):
        super().__init__(line_scan_rate=[[0.5, 0.0, 1.0]], **pose)
        self.framelet_height = int(framelet_height)
        self.exposure_duration = float(exposure_duration)
        self.interframe_delay = float(interframe_delay)
        self.starting_time = float(starting_time)
        self.framelets_flipped = bool(framelets_flipped)
        self.framelet_order_reversed = bool(framelet_order_reversed)
        summing = float(self.detector.line_summing)
        self.summed_height = int(self.framelet_height / summing)
        if self.framelet_height <= 0 or self.summed_height <= 0:
            raise ValueError(f"{self.name}: framelet height {framelet_height} (line summing "
                             f"{summing:g}) gives no line per framelet")
        if self.interframe_delay <= 0 or self.exposure_duration < 0:
            raise ValueError(f"{self.name}: interframe delay {interframe_delay} s and "
                             f"exposure {exposure_duration} s must be positive")
        self.n_framelets = self.lines // self.summed_height
        if self.n_framelets < 1:
            raise ValueError(f"{self.name}: {self.lines} image lines hold no framelet of "
                             f"{self.summed_height} lines")

    def __repr__(self) -> str:
        return (f"PushFrameSensor(name={self.name!r}, size={self.lines}x{self.samples}, "
                f"{self.n_framelets} framelets of {self.framelet_height} lines, "
                f"f={self.focal_length} mm, distortion={self.distortion.model})")

    # -- time ------------------------------------------------------------------------
    def framelet(self, line) -> np.ndarray:
        """Framelet number (int64, in image order) of image lines."""
        return self._framelet_of(line)

    def _framelet_of(self, line) -> np.ndarray:
        """:meth:`framelet` of lines of the full image (not overridden by windows)."""
        line = np.asarray(line, dtype=np.float64)
        k = np.trunc(line / self.summed_height).astype(np.int64)
        # the last framelet's bottom edge (line = n_framelets · h, the image's edge when
        # it holds whole framelets) is that framelet's, not the start of one more that
        # was never exposed (issue 46: no ray at line = image_lines)
        edge = self.n_framelets * self.summed_height
        return np.where((k == self.n_framelets) & (line <= edge), k - 1, k)

    def framelet_time(self, framelet) -> np.ndarray:
        """Exposure time (seconds from the centre time) of framelets in image order."""
        k = np.asarray(framelet, dtype=np.float64)
        if self.framelet_order_reversed:
            k = self.n_framelets - k - 1
        return self.starting_time + 0.5 * self.exposure_duration + k * self.interframe_delay

    def line_time(self, line) -> np.ndarray:
        """Exposure time (seconds from the centre time) of image lines (usgscsm
        ``getImageTime``: the time of the line's framelet)."""
        return self.framelet_time(self.framelet(line))

    def time_line(self, time) -> np.ndarray:
        """Centre line of the framelet exposed nearest ``time`` (inverse of
        :meth:`line_time` up to the framelet)."""
        k = np.rint((np.asarray(time, dtype=np.float64) - self.starting_time
                     - 0.5 * self.exposure_duration) / self.interframe_delay)
        if self.framelet_order_reversed:
            k = self.n_framelets - k - 1
        return (k + 0.5) * self.summed_height

    # -- image → ground --------------------------------------------------------------
    def _detector_line(self, line) -> np.ndarray:
        line = np.asarray(line, dtype=np.float64)
        within = line - self._framelet_of(line) * self.summed_height
        return self.summed_height - within if self.framelets_flipped else within

    def image_to_ray(self, line, sample) -> Ray:
        """Imaging rays (CSM convention: the first pixel's centre at ``(0.5, 0.5)``), each
        from the sensor position at its framelet's exposure time (:meth:`line_time`) and
        the line within its framelet (:meth:`_detector_line`): the numpy form of
        :meth:`LineScanSensor.image_to_ray` (whose compiled kernel times one detector
        line); body-fixed metres, rays towards the body."""
        return self._image_to_ray_numpy(line, sample)

    # -- ground → image --------------------------------------------------------------
    def _view(self, framelet, xyz):
        """Detector (line, sample) within ``framelet`` (N,) of points (N, 3), and depth."""
        time = self.framelet_time(framelet)
        position = self.position_at(time)
        rotation = self.rotation_at(time)
        cam = np.einsum("nji,nj->ni", rotation, xyz - position)  # Rᵀ (X − C)
        toward = np.where(np.sum(rotation[..., :, 2] * position, axis=-1) > 0, -1.0, 1.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = self.focal_length / cam[..., 2]
            dx, dy = self.distortion.apply(cam[..., 0] * scale, cam[..., 1] * scale)
        det_line, det_sample = self.detector.to_pixel(dx, dy)
        return det_line, det_sample, toward * cam[..., 2]

    def _frame_distance(self, framelet, xyz) -> np.ndarray:
        """usgscsm ``calcFrameDistance``: the detector line of the points seen from the
        framelet's exposure minus the framelet's middle line (no distortion applied)."""
        time = self.framelet_time(framelet)
        position = self.position_at(time)
        rotation = self.rotation_at(time)
        cam = np.einsum("nji,nj->ni", rotation, xyz - position)
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = self.focal_length / cam[..., 2]
            line, _ = self.detector.to_pixel(cam[..., 0] * scale, cam[..., 1] * scale)
        return line - 0.5 * self.summed_height

    def ground_to_image(self, xyz, *, framelet=None, max_iterations: int = 20
                        ) -> tuple[np.ndarray, np.ndarray]:
        """Image coordinates of body-fixed points (see the module docstring).

        Parameters
        ----------
        xyz : S + (3,) float
            Body-fixed metres.
        framelet : int or array broadcastable to S, optional
            Project into these framelets (image order) instead of searching: a ground
            point in the overlap of two framelets has an image in each, and this picks
            one (e.g. the framelet an image point came from, for a round trip).

        Returns
        -------
        line, sample : arrays of shape S (CSM convention); NaN behind the sensor or
        where the framelet search fails.
        """
        xyz = np.asarray(xyz, dtype=np.float64)
        shape = xyz.shape[:-1]
        pts = xyz.reshape(-1, 3)
        n = len(pts)
        last = self.n_framelets - 1
        if framelet is not None:
            best = np.broadcast_to(np.asarray(framelet, dtype=np.int64), shape).reshape(-1)
            return self._project(np.clip(best, 0, last), pts, shape)
        start = np.zeros(n, dtype=np.int64)
        end = np.full(n, last, dtype=np.int64)
        d_start = self._frame_distance(start, pts)
        d_end = self._frame_distance(end, pts)
        active = (start != end) & (d_start != d_end) & np.isfinite(d_start) & np.isfinite(d_end)
        for _ in range(max_iterations):
            idx = np.flatnonzero(active)
            if not len(idx):
                break
            offset = d_end[idx] * (end[idx] - start[idx]) / (d_end[idx] - d_start[idx])
            start[idx], d_start[idx] = end[idx], d_end[idx]
            stepped = np.rint(end[idx] - offset)
            end[idx] = np.clip(np.where(np.isfinite(stepped), stepped, end[idx]), 0,
                               last).astype(np.int64)
            d_end[idx] = self._frame_distance(end[idx], pts[idx])
            active[idx] = ((start[idx] != end[idx]) & (d_start[idx] != d_end[idx])
                           & np.isfinite(d_end[idx]))
        # The secant stops near a framelet that sees the point.  Of it and its neighbours
        # keep one whose projection (distortion included) falls on its own detector lines
        # — a point projected into a framelet outside its lines would be read back
        # through another framelet's pose, on other ground — the one nearest its middle
        # line where neighbours overlap (usgscsm's criterion); failing that, the nearest
        # middle line (calcFrameDistance).
        best, d_best = end, np.abs(d_end)
        for step in (-1, 1):
            other = np.clip(end + step, 0, last)
            d_other = np.abs(self._frame_distance(other, pts))
            better = d_other < d_best
            best = np.where(better, other, best)
            d_best = np.where(better, d_other, d_best)
        h = float(self.summed_height)
        chosen, d_chosen = best.copy(), np.full(n, np.inf)
        for step in (-2, -1, 0, 1, 2):
            other = np.clip(end + step, 0, last)
            det_line, det_sample, depth = self._view(other, pts)
            if self.framelets_flipped:
                det_line = h - det_line
            on = (det_line >= 0) & (det_line <= h) & (depth > 0) & np.isfinite(det_sample)
            distance = np.where(on, np.abs(det_line - 0.5 * h), np.inf)
            better = distance < d_chosen
            chosen = np.where(better, other, chosen)
            d_chosen = np.where(better, distance, d_chosen)
        return self._project(chosen, pts, shape)

    def _project(self, best, pts, shape):
        """(line, sample) of points (N, 3) projected into framelets ``best`` (N,)."""
        det_line, det_sample, depth = self._view(best, pts)
        if self.framelets_flipped:  # the inverse of image_to_ray's flip (usgscsm omits it)
            det_line = self.summed_height - det_line
        line = det_line + best * self.summed_height
        bad = ~(depth > 0) | ~np.isfinite(line) | ~np.isfinite(det_sample)
        uncovered = self._uncovered(best * self.summed_height + 0.5)
        if uncovered is not None:  # inside the image only (see LineScanSensor)
            bad |= uncovered & (line >= 0) & (line <= self.lines)
        line = np.where(bad, np.nan, line)
        sample = np.where(bad, np.nan, det_sample)
        return line.reshape(shape), sample.reshape(shape)

    def _affine_guess(self):  # the line search of the line-scan model is not used
        raise NotImplementedError

    def _detector_view_fast(self, line, xyz):  # pragma: no cover - not used
        raise NotImplementedError


#: The ISD keys of the framelet geometry and timing (usgscsm ``constructStateFromIsd``).
FRAMELET_KEYS = ("framelet_height", "exposure_duration", "interframe_delay",
                 "starting_ephemeris_time", "framelets_flipped", "framelet_order_reversed")


def framelet_keys(keys, isd, center_time: float) -> dict:
    """The :class:`PushFrameSensor` framelet arguments of an ALE push-frame ISD.

    ``keys`` is the ISD reader's key helper (its errors name the file and the key).
    usgscsm refuses an ISD without them ("Could not parse the framelet timing
    information"); so does this, naming the first key missing.
    """
    from demtool.errors import InputError

    values = {k: keys.get(isd, k) for k in FRAMELET_KEYS}
    for flag in ("framelets_flipped", "framelet_order_reversed"):
        if not isinstance(values[flag], bool):
            raise InputError(f"{keys.source}: ISD key '{flag}' is {values[flag]!r}, expected "
                             "true or false")
    try:
        numbers = {k: float(values[k]) for k in FRAMELET_KEYS[:4]}
    except (TypeError, ValueError):
        raise InputError(f"{keys.source}: ISD framelet keys must be numbers "
                         f"({', '.join(FRAMELET_KEYS[:4])})") from None
    for key, number in numbers.items():
        if not np.isfinite(number):
            raise InputError(f"{keys.source}: ISD key '{key}' is {values[key]!r}: not a "
                             "finite number")
    if numbers["framelet_height"] != int(numbers["framelet_height"]):
        raise InputError(f"{keys.source}: ISD key 'framelet_height' is "
                         f"{values['framelet_height']!r}, expected a whole number of lines")
    return dict(framelet_height=int(numbers["framelet_height"]),
                exposure_duration=numbers["exposure_duration"],
                interframe_delay=numbers["interframe_delay"],
                starting_time=numbers["starting_ephemeris_time"] - center_time,
                framelets_flipped=values["framelets_flipped"],
                framelet_order_reversed=values["framelet_order_reversed"])
