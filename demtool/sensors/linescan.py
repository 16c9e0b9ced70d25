"""Line-scan (pushbroom) camera: usgscsm's ``UsgsAstroLsSensorModel``.

Each image line is exposed at its own time, ``t = t_i + r_i (line − line_i + 0.5)``
for the piece ``i`` of the line-scan-rate table holding ``line`` (times relative to
the image's centre time).  At that time the sensor position comes from Lagrange
interpolation (order 8 inside, lower near the ends) of the equally spaced ephemeris,
and the sensor-to-body rotation from Lagrange interpolation of the equally spaced
quaternion components, normalised — both exactly as usgscsm's ``getAdjSensorPosVel``
and ``getQuaternions`` do.  The detector is one line: a sample maps to the focal
plane with detector line 0, and the camera looks along ``(−u, −v, −f)``
(``createCameraLookVector`` with ``zDirection = 1``).

Ground to image is iterative, as in usgscsm: find the line whose exposure sees the
ground point on the detector line (detector-line coordinate 0), here by a
vectorised chord (fixed-slope Newton) steps from an affine approximation of the model,
then read the sample from the same projection.  Each step's pose and projection run
compiled, one point per thread (:mod:`demtool.sensors.kernels`), and so does the
pose and look vector of image to ground; the lens distortion is applied and removed
with numpy.  Light time and aberration are ignored, as usgscsm
does by default.

Reference: DOI-USGS/usgscsm ``src/UsgsAstroLsSensorModel.cpp`` (``getImageTime``,
``losToEcf``, ``computeDetectorView``, ``groundToImage``, ``getSunPosition``).
"""

from __future__ import annotations

import numpy as np

from demtool.sensors.base import Detector, Ray, SensorModel, lagrange_interp, quaternion_to_matrix
from demtool.sensors.distortion import Distortion


class LineScanSensor(SensorModel):
    """A CSM pushbroom camera in a body-fixed frame.

    Parameters
    ----------
    line_scan_rate : (K, 3) float
        Rows ``(line, time, seconds_per_line)``: from image line ``line`` on, lines are
        exposed every ``seconds_per_line`` starting at ``time`` (seconds from the
        centre time), ALE's ``line_scan_rate``.
    positions : (n, 3) float
        Sensor positions, body-fixed metres, at times ``t0_ephem + i * dt_ephem``.
    quaternions : (m, 4) float
        Sensor-to-body rotations, scalar-last ``(x, y, z, w)``, at times
        ``t0_quat + j * dt_quat`` (m = 1: constant attitude).
    focal_length : float
        Millimetres.
    detector : Detector
        Interior orientation.
    distortion : Distortion
    lines, samples : int
        Image size.
    radii : (float, float)
        Body semi-axes, metres.
    sun_positions : (k, 3) float
        Sun positions, body-fixed metres (usgscsm's spacing convention, see
        :meth:`sun_position`).
    sun_velocities : (k, 3) float, optional
        Used when there is one sun position: linear extrapolation in time.
    velocities : (n, 3) float, optional
        Sensor velocities (m/s), kept for later stages (not used by the geometry).
    """

    kind = "linescan"

    def __init__(self, *, line_scan_rate, positions, t0_ephem: float, dt_ephem: float,
                 quaternions, t0_quat: float, dt_quat: float, focal_length: float,
                 detector: Detector, distortion: Distortion | None = None, lines: int,
                 samples: int, radii: tuple[float, float], sun_positions=None,
                 sun_velocities=None, velocities=None, name: str = "",
                 center_time: float = 0.0):
        rate = np.asarray(line_scan_rate, dtype=np.float64).reshape(-1, 3)
        order = np.argsort(rate[:, 0], kind="stable")
        self.int_lines = rate[order, 0]
        self.int_start_times = rate[order, 1]
        self.int_times = rate[order, 2]
        self.positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        self.velocities = (None if velocities is None
                           else np.asarray(velocities, dtype=np.float64).reshape(-1, 3))
        self.t0_ephem = float(t0_ephem)
        self.dt_ephem = float(dt_ephem) if len(self.positions) > 1 else 1.0
        q = np.asarray(quaternions, dtype=np.float64).reshape(-1, 4).copy()
        for i in range(1, len(q)):  # keep one hemisphere so component interpolation works
            if np.dot(q[i], q[i - 1]) < 0:
                q[i] = -q[i]
        self.quaternions = q
        self.t0_quat = float(t0_quat)
        self.dt_quat = float(dt_quat) if len(q) > 1 else 1.0
        self.focal_length = float(focal_length)
        self.detector = detector
        self.distortion = distortion if distortion is not None else Distortion()
        self.lines = int(lines)
        self.samples = int(samples)
        self.radii = (float(radii[0]), float(radii[1]))
        self.sun_positions = (np.zeros((1, 3)) if sun_positions is None
                              else np.asarray(sun_positions, dtype=np.float64).reshape(-1, 3))
        self.sun_velocities = (None if sun_velocities is None
                               else np.asarray(sun_velocities, dtype=np.float64).reshape(-1, 3))
        self.name = str(name)
        self.center_time = float(center_time)
        self._affine = None

    def __repr__(self) -> str:
        return (f"LineScanSensor(name={self.name!r}, size={self.lines}x{self.samples}, "
                f"f={self.focal_length} mm, distortion={self.distortion.model}, "
                f"{len(self.positions)} positions, {len(self.quaternions)} quaternions)")

    # -- time, position, attitude ---------------------------------------------------
    def line_time(self, line) -> np.ndarray:
        """Exposure time (seconds from the centre time) of image lines (CSM convention)."""
        line = np.asarray(line, dtype=np.float64)
        index = np.searchsorted(self.int_lines, line, side="right") - 1
        index = np.clip(index, 0, len(self.int_lines) - 1)
        return (self.int_start_times[index]
                + self.int_times[index] * (line - self.int_lines[index] + 0.5))

    def time_line(self, time) -> np.ndarray:
        """Image line exposed at ``time`` (inverse of :meth:`line_time`)."""
        time = np.asarray(time, dtype=np.float64)
        order = np.argsort(self.int_start_times, kind="stable")
        starts = self.int_start_times[order]
        index = order[np.clip(np.searchsorted(starts, time, side="right") - 1, 0,
                              len(starts) - 1)]
        return ((time - self.int_start_times[index]) / self.int_times[index]
                + self.int_lines[index] - 0.5)

    def position_at(self, time) -> np.ndarray:
        """Sensor position (body-fixed metres) at times (seconds from centre), S + (3,)."""
        time = np.asarray(time, dtype=np.float64)
        if len(self.positions) == 1:
            return np.broadcast_to(self.positions[0], time.shape + (3,)).copy()
        out = lagrange_interp(self.positions, self.t0_ephem, self.dt_ephem, time.reshape(-1), 8)
        return out.reshape(time.shape + (3,))

    def rotation_at(self, time) -> np.ndarray:
        """Sensor-to-body rotation matrices at times, S + (3, 3)."""
        time = np.asarray(time, dtype=np.float64)
        if len(self.quaternions) == 1:
            q = np.broadcast_to(self.quaternions[0], time.shape + (4,))
        else:
            order = 4 if len(self.quaternions) * 4 < 6 else 8
            q = lagrange_interp(self.quaternions, self.t0_quat, self.dt_quat,
                                time.reshape(-1), order).reshape(time.shape + (4,))
        return quaternion_to_matrix(q)

    # -- interface --------------------------------------------------------------------
    def image_to_ray(self, line, sample) -> Ray:
        """Imaging rays; the first pixel's centre is at ``(line, sample) = (0.5, 0.5)``.

        The exposure pose and the look vector of each point are computed compiled
        (:func:`demtool.sensors.kernels.image_rays`); :meth:`_image_to_ray_numpy` is the
        same computation in numpy.  Returns origins (body-fixed metres) and unit
        directions, both of shape ``broadcast(line, sample).shape + (3,)``.
        """
        from demtool.sensors.kernels import image_rays

        line, sample = np.broadcast_arrays(np.asarray(line, dtype=np.float64),
                                           np.asarray(sample, dtype=np.float64))
        x, y = self.detector.to_focal_plane(np.zeros_like(sample), sample)
        u, v = self.distortion.remove(x, y)
        origin, look = image_rays(
            np.ascontiguousarray(line.reshape(-1)),
            np.ascontiguousarray(np.broadcast_to(u, line.shape).reshape(-1)),
            np.ascontiguousarray(np.broadcast_to(v, line.shape).reshape(-1)),
            self.int_lines, self.int_start_times, self.int_times, self.positions,
            self.t0_ephem, self.dt_ephem, self.quaternions, self.t0_quat, self.dt_quat,
            self._quat_order(), self.focal_length)
        return self._masked(line, Ray(origin.reshape(line.shape + (3,)),
                                      look.reshape(line.shape + (3,))))

    def _uncovered(self, line) -> np.ndarray | None:
        """Where lines are exposed outside the sampled ephemeris (None: all covered or
        coverage not known); see :mod:`demtool.sensors.coverage`."""
        if self.coverage is None:
            return None
        out = ~self.coverage.covers(self.line_time(line))
        return out if np.any(out) else None

    def _masked(self, line, ray: Ray) -> Ray:
        """NaN rays for image lines (0 ≤ line ≤ lines) outside the ephemeris coverage;
        lines beyond the image are left to the caller, which extrapolates knowingly."""
        bad = self._uncovered(line)
        if bad is None:
            return ray
        bad = bad & (line >= 0) & (line <= self.lines)
        return Ray(np.where(bad[..., None], np.nan, ray.origin),
                   np.where(bad[..., None], np.nan, ray.direction))

    def _quat_order(self) -> int:
        """Highest Lagrange order of the quaternion interpolation (as :meth:`rotation_at`)."""
        return 4 if len(self.quaternions) * 4 < 6 else 8

    def _detector_line(self, line) -> np.ndarray:
        """The detector line an image line is exposed on: 0 for a line scanner (one
        detector line); a push-frame sensor's line within its framelet."""
        return np.zeros_like(np.asarray(line, dtype=np.float64))

    def _image_to_ray_numpy(self, line, sample) -> Ray:
        """:meth:`image_to_ray` in numpy (the reference the compiled kernel must match)."""
        line, sample = np.broadcast_arrays(np.asarray(line, dtype=np.float64),
                                           np.asarray(sample, dtype=np.float64))
        time = self.line_time(line)
        origin = self.position_at(time)
        x, y = self.detector.to_focal_plane(self._detector_line(line), sample)
        u, v = self.distortion.remove(x, y)
        look_cam = np.stack([-u, -v, np.full(u.shape, -self.focal_length)], axis=-1)
        look = np.sum(self.rotation_at(time) * look_cam[..., None, :], axis=-1)
        # usgscsm looks along (−u, −v, −f) and intersects at the root nearest the sensor
        # whatever its sign; real ISDs put the body on the +z side.  Orient each ray
        # towards the body so that s > 0 is in front of the sensor.
        sign = np.where(np.sum(look * origin, axis=-1) > 0, -1.0, 1.0)
        look *= (sign / np.linalg.norm(look, axis=-1))[..., None]
        return self._masked(line, Ray(origin, look))

    def _detector_view(self, line, xyz):
        """Detector (line, sample) of points seen from the exposure of image ``line``."""
        time = self.line_time(line)
        position = self.position_at(time)
        rel = xyz - position
        rotation = self.rotation_at(time)
        cam = np.sum(rotation * rel[..., :, None], axis=-2)  # Rᵀ rel
        # Depth along the camera axis on the body's side (see image_to_ray).
        toward = np.where(np.sum(rotation[..., :, 2] * position, axis=-1) > 0, -1.0, 1.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = self.focal_length / cam[..., 2]
            fx, fy = cam[..., 0] * scale, cam[..., 1] * scale
        dx, dy = self.distortion.apply(fx, fy)
        det_line, det_sample = self.detector.to_pixel(dx, dy)
        return det_line, det_sample, toward * cam[..., 2]

    def _detector_view_fast(self, line, xyz):
        """:meth:`_detector_view` with the pose and projection compiled
        (:func:`demtool.sensors.kernels.detector_view`); line (N,), xyz (N, 3)."""
        from demtool.sensors.kernels import detector_view

        fx, fy, depth = detector_view(
            np.ascontiguousarray(line, dtype=np.float64),
            np.ascontiguousarray(xyz, dtype=np.float64), self.int_lines,
            self.int_start_times, self.int_times, self.positions, self.t0_ephem,
            self.dt_ephem, self.quaternions, self.t0_quat, self.dt_quat, self._quat_order(),
            self.focal_length)
        dx, dy = self.distortion.apply(fx, fy)
        det_line, det_sample = self.detector.to_pixel(dx, dy)
        return det_line, det_sample, depth

    def _affine_guess(self):
        """Affine map XYZ → (line, sample) from a grid of image_to_ground points, and the
        slope of the detector line with the image line at the image centre."""
        if self._affine is None:
            ll, ss = np.meshgrid(np.linspace(0.5, self.lines - 0.5, 5),
                                 np.linspace(0.5, self.samples - 0.5, 5), indexing="ij")
            pts = [self.image_to_ground(ll, ss, h).reshape(-1, 3) for h in (-1000.0, 1000.0)]
            xyz = np.concatenate(pts)
            target = np.column_stack([np.tile(ll.ravel(), 2), np.tile(ss.ravel(), 2)])
            finite = np.all(np.isfinite(xyz), axis=1)  # lines outside the coverage: NaN
            xyz, target = xyz[finite], target[finite]
            if len(xyz) < 4:
                raise ValueError(f"{self.name}: no image line lies within the sampled "
                                 "ephemeris")
            design = np.column_stack([xyz - xyz.mean(axis=0), np.ones(len(xyz))])
            coef, *_ = np.linalg.lstsq(design, target, rcond=None)
            rows = target[:, 0]  # the covered grid line nearest the middle
            mid = float(rows[np.argmin(np.abs(rows - np.median(rows)))])
            centre = self.image_to_ground(mid, 0.5 * self.samples)[None]
            ahead, _, _ = self._detector_view(np.array([mid + 0.5]), centre)
            behind, _, _ = self._detector_view(np.array([mid - 0.5]), centre)
            slope = float(ahead[0] - behind[0])
            if not np.isfinite(slope) or slope == 0:
                raise ValueError(f"{self.name}: the detector line does not move with the "
                                 "image line (degenerate line-scan geometry)")
            self._affine = (xyz.mean(axis=0), coef, slope)
        return self._affine

    def ground_to_image(self, xyz, *, precision: float = 1e-6, max_iterations: int = 30,
                        start_line=None) -> tuple[np.ndarray, np.ndarray]:
        """Image coordinates of body-fixed points, iteratively (see module docstring).

        Parameters
        ----------
        xyz : S + (3,) float
            Body-fixed metres.
        precision : float
            Convergence tolerance on the line, pixels.
        start_line : array of shape S, optional
            A first guess of the lines (NaN: none), e.g. a nearby point's (bundle
            adjustment's derivatives); the iteration starts there instead of at the
            affine guess.

        Returns
        -------
        line, sample : arrays of shape S (CSM convention); NaN where the iteration
        does not converge or the point is behind the sensor.
        """
        xyz = np.asarray(xyz, dtype=np.float64)
        shape = xyz.shape[:-1]
        pts = xyz.reshape(-1, 3)
        mean, coef, slope = self._affine_guess()
        line = np.column_stack([pts - mean, np.ones(len(pts))]) @ coef[:, 0]
        if start_line is not None:
            guess = np.broadcast_to(np.asarray(start_line, dtype=np.float64), shape).reshape(-1)
            line = np.where(np.isfinite(guess), guess, line)
        det_line = np.full(len(pts), np.nan)
        sample = np.full(len(pts), np.nan)
        depth = np.full(len(pts), np.nan)
        active = np.arange(len(pts))
        # The first step uses the slope d(det_line)/d(line) of the image centre (chord);
        # later steps the secant through each point's last two evaluations, since the
        # slope can vary by 2× across an image (strong distortion, varying line rates).
        prev_line = np.full(len(pts), np.nan)
        prev_f = np.full(len(pts), np.nan)
        for _ in range(max_iterations):
            if not len(active):
                break
            f, smp, dep = self._detector_view_fast(line[active], pts[active])
            det_line[active], sample[active], depth[active] = f, smp, dep
            with np.errstate(divide="ignore", invalid="ignore"):
                secant = (f - prev_f[active]) / (line[active] - prev_line[active])
            usable = np.isfinite(secant) & (np.abs(secant) > 1e-12)
            step = -f / np.where(usable, secant, slope)
            prev_line[active], prev_f[active] = line[active], f
            line[active] += step
            keep = np.abs(step) > precision
            done = active[~keep]
            if len(done):  # the last step moved the line by < precision: refresh the sample
                f, smp, dep = self._detector_view_fast(line[done], pts[done])
                det_line[done], sample[done], depth[done] = f, smp, dep
            active = active[keep & np.isfinite(step)]
        bad = ~np.isfinite(line) | ~(depth > 0) | ~(np.abs(det_line) < 1e-3)
        guess = np.column_stack([pts - mean, np.ones(len(pts))]) @ coef[:, 0]
        lost = bad | (((line < 0) | (line > self.lines)) & (guess >= 0) & (guess <= self.lines))
        if np.any(lost):  # several lines see the point (a scan mirror): bracket the zero
            found = self._bracketed_lines(pts[lost], precision)
            ok = np.isfinite(found[0])
            idx = np.flatnonzero(lost)[ok]
            line[idx], sample[idx] = found[0][ok], found[1][ok]
            bad[idx] = False
        # a point seen by an image line outside the sampled ephemeris has no image; lines
        # beyond the image stay (callers such as mapproject's lattice extrapolate them)
        uncovered = self._uncovered(np.where(bad, 0.5 * self.lines, line))
        if uncovered is not None:
            bad |= uncovered & (line >= 0) & (line <= self.lines)
        line = np.where(bad, np.nan, line)
        sample = np.where(bad, np.nan, sample)
        return line.reshape(shape), sample.reshape(shape)

    def _bracketed_lines(self, pts, precision: float, n_lines: int = 257):
        """(line, sample) of points (N, 3) found by scanning the image's lines for a sign
        change of the detector line (in front of the sensor), then bisection: for models
        whose detector line is not monotonic in the image line (a scanning mirror sees
        the same ground from several lines), where the secant search of
        :meth:`ground_to_image` fails.  NaN where no image line sees the point."""
        lines = np.linspace(0.0, float(self.lines), min(n_lines, 2 * self.lines + 1))
        n = len(pts)
        grid_l = np.repeat(lines[None, :], n, axis=0)
        grid_p = np.repeat(pts[:, None, :], len(lines), axis=1)
        f, _, depth = self._detector_view_fast(grid_l.reshape(-1), grid_p.reshape(-1, 3))
        f = np.where(depth > 0, f, np.nan).reshape(n, len(lines))
        change = (np.sign(f[:, :-1]) * np.sign(f[:, 1:]) <= 0) & np.isfinite(f[:, :-1]) \
            & np.isfinite(f[:, 1:])
        has = np.any(change, axis=1)
        first = np.argmax(change, axis=1)
        lo = lines[first].copy()
        hi = lines[np.minimum(first + 1, len(lines) - 1)].copy()
        f_lo = f[np.arange(n), first]
        out_line = np.full(n, np.nan)
        out_sample = np.full(n, np.nan)
        if not np.any(has):
            return out_line, out_sample
        sel = np.flatnonzero(has)
        lo, hi, f_lo = lo[sel], hi[sel], f_lo[sel]
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            f_mid, _, _ = self._detector_view_fast(mid, pts[sel])
            left = np.sign(f_mid) * np.sign(f_lo) <= 0
            hi = np.where(left, mid, hi)
            lo, f_lo = np.where(left, lo, mid), np.where(left, f_lo, f_mid)
            if np.all(hi - lo < precision):
                break
        mid = 0.5 * (lo + hi)
        f_mid, smp, dep = self._detector_view_fast(mid, pts[sel])
        good = (np.abs(f_mid) < 1e-3) & (dep > 0)
        out_line[sel] = np.where(good, mid, np.nan)
        out_sample[sel] = np.where(good, smp, np.nan)
        return out_line, out_sample

    def sun_position(self, line) -> np.ndarray:
        """Sun position (body-fixed metres, S + (3,)) at the exposure of ``line``.

        As usgscsm's ``getSunPosition``: several positions are Lagrange-interpolated
        on usgscsm's grid (start ``t0_ephem``, spacing
        ``dt_ephem · n_positions / n_sun``); one position with a velocity is
        extrapolated linearly in time; otherwise the one position is returned.
        """
        time = self.line_time(line)
        n_sun = len(self.sun_positions)
        if n_sun > 1:
            dt = self.dt_ephem * len(self.positions) / n_sun
            out = lagrange_interp(self.sun_positions, self.t0_ephem, dt, time.reshape(-1), 8)
            return out.reshape(time.shape + (3,))
        if self.sun_velocities is not None and len(self.sun_velocities):
            return self.sun_positions[0] + time[..., None] * self.sun_velocities[0]
        return np.broadcast_to(self.sun_positions[0], time.shape + (3,)).copy()

    def camera_center(self, line) -> np.ndarray:
        """Sensor position (body-fixed metres, S + (3,)) at the exposure of ``line``."""
        return self.position_at(self.line_time(line))
