"""Ego-motion: the scanner's motion between scans from odometry plus ICP scan matching.

No ROS; the scan matching is a compiled kernel (:mod:`laser_tracker.core.icp`), and so are
the fusion's algebra and the adaptive prior's update (one call each per scan). Usage, one
estimator per scan stream::

    est = EgoMotionEstimator(EgoMotionConfig())
    est.add_odometry(stamp, (x, y, theta))     # every odometry sample, as it arrives
    e = est.update(scan)                       # every Scan -> EgoMotionEstimate
    e.pose      # (3,) scanner pose in the odometry frame (NaN only when source == 'none')
    e.motion    # (3,) motion since the previous scan (previous scanner frame)
    e.covariance, e.source, e.reason, e.coasting, e.ok

Offline, with the whole odometry as a PoseTrack: :func:`estimate_track`.

Roles: :class:`OdometryBuffer` (the odometry stream), :class:`MotionPrior` (the prediction
and its adaptive noise), :class:`ScanMatcher` (the scan's points, the local map and ICP),
:func:`fuse` (ICP and the prediction by information) and :func:`implausible` (the checks of
the fused motion); :class:`EgoMotionEstimator` holds the pose chain and runs them per scan.

Method (per scan):

1. The prediction. Odometry is interpolated at ``scan.stamp + odom_latency`` (odometry
   stamped late by ``odom_latency`` seconds) and the scanner's mounting (``mount_*``)
   applied; the increment since the previous scan is the prediction. Without a usable
   increment (no odometry, late, a gap, or a jump: a segment break or a step faster than the
   platform) the prediction is the previous motion scaled to the time step (constant
   velocity). Either is a Gaussian prior.
2. The prior's noise adapts (``adaptive_prior``, :class:`AdaptiveNoise`): each accepted,
   fully constrained match gives the disagreement between the prediction in use (odometry,
   else constant velocity) and the ICP motion; its square minus the ICP's own variance
   samples the prediction's variance, fitted per step, per metre and per radian (robust
   running least squares over ``adaptive_memory`` matches, starting from the fixed
   ``odom_sigma_*`` / ``cv_sigma_*`` model). So good odometry comes to be trusted and poor
   odometry not, with the same defaults and no per-robot tuning.
3. The scan's valid points (``Scan.valid()`` and ``min_range``/``max_range``, at most
   ``max_points``) are matched by point-to-line ICP (:mod:`laser_tracker.core.icp`) against a
   local map of the last ``map_scans`` key scans placed with their estimated poses, starting
   at the prediction, with coarse-to-fine association distances (``association_distance`` down
   to ``association_distance_final``) and Cauchy weights.
4. ICP and the prediction are fused by information: the ICP direction constrained by a
   fraction ``lambda`` of the points (eigenvalues of the normalised Hessian) gets the variance
   ``icp_model_sigma**2 / lambda``; the prior's information is at most ``prior_max_ratio``
   times the match's per axis, and a match more than ``prior_gate`` combined sigmas from the
   prediction overrides it (a wheel slip). Directions with ``lambda < degeneracy_threshold``
   (a featureless corridor, a single wall) take the prediction exactly (source
   ``icp_partial``).
5. Checks: enough points, overlap (``min_inlier_ratio``), residual (``max_rms``),
   convergence, the platform's speed limits (``max_translation_speed``,
   ``max_rotation_speed``) and the disagreement with odometry (``max_correction_*``).
   A refused match never restarts the pose chain: the platform coasts on its prediction
   (source ``odometry`` or ``constant_velocity``, ``coasting`` True; detection gates such a
   scan, see ``difference.pose_quality``). After ``max_lost_scans`` scans in a row without a
   match (or at once when the map is too small to match against) the local map is re-seeded
   from the current scan at its coasted pose; the pose chain goes on.

Sources: ``init`` (first scan or an explicit reset: pose = odometry pose or the origin,
motion 0), ``icp``, ``icp_partial`` (ICP with the prediction along the degenerate
directions), ``odometry`` (no match: the odometry increment; reason says why),
``constant_velocity`` (no match and no usable odometry: the previous motion), ``none`` (no
pose: a scan with the same stamp as the previous one). ``reason`` is a short text for logs.

Bad input is never fatal: non-finite/non-positive ranges are not points; too few points or
an all-max-range scan coast on the prediction; odometry that is missing, late (beyond
``odom_max_extrapolation``), has a gap (``odom_max_gap``), jumps (faster than the platform),
arrives out of order (inserted in order) or goes back in time by more than
``odom_reset_threshold`` (buffer cleared) is handled in :class:`OdometryBuffer`; a scan
stamped before the previous one resets the estimator (a bag replayed in a loop), one with
the same stamp is skipped. Each case is logged (rate-limited) with its reason and counted
in ``stats``.
"""
from __future__ import annotations

import bisect
import logging
import math
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from laser_tracker.config import param
from laser_tracker.core import icp, jit
from laser_tracker.core.geometry import between, compose, plain_floats, wrap_scalar
from laser_tracker.core.scan import Scan, beam_table

log = logging.getLogger(__name__)

SOURCE_INIT = 'init'
SOURCE_ICP = 'icp'
SOURCE_PARTIAL = 'icp_partial'
SOURCE_ODOMETRY = 'odometry'
SOURCE_CONSTANT_VELOCITY = 'constant_velocity'
SOURCE_NONE = 'none'
SOURCES = (SOURCE_INIT, SOURCE_ICP, SOURCE_PARTIAL, SOURCE_ODOMETRY, SOURCE_CONSTANT_VELOCITY,
           SOURCE_NONE)

_PI = 3.141592653589793


@dataclass(frozen=True)
class EgoMotionConfig:
    """Section ``ego_motion``: odometry prior, ICP and the acceptance checks."""

    # --- scanner mounting (base_link -> laser)
    mount_x: float = param(0.0, 'Scanner position on the platform, forward (m).',
                           min=-10.0, max=10.0)
    mount_y: float = param(0.0, 'Scanner position on the platform, left (m).',
                           min=-10.0, max=10.0)
    mount_yaw: float = param(0.0, 'Scanner yaw on the platform (rad).', min=-_PI, max=_PI)
    # --- odometry
    odom_latency: float = param(
        0.0, 'Odometry time stamps minus the true time of the pose (s): the pose for a scan '
        'stamped t is read at t + latency (the paper\'s "delays and timing errors").',
        min=-2.0, max=2.0)
    odom_max_extrapolation: float = param(
        0.1, 'Odometry older than the scan by at most this (s) is extrapolated at its last '
        'velocity; older means "odometry late" (no odometry for that scan).', min=0.0, max=2.0)
    odom_max_gap: float = param(
        2.0, 'Largest time between two odometry samples to interpolate across (s).',
        min=0.001, max=60.0)
    odom_buffer: float = param(30.0, 'Odometry history kept behind the latest scan (s).',
                               min=1.0, max=3600.0)
    odom_reset_threshold: float = param(
        1.0, 'An odometry sample older than the newest by more than this (s) is a restart '
        '(bag loop): the buffer is cleared. Younger ones are inserted in time order.',
        min=0.0, max=3600.0)
    odom_sigma_xy: float = param(
        0.01, 'Odometry increment noise per scan step, each of x and y (m, 1 sigma); with '
        'adaptive_prior: the starting value, then adapted.', min=1e-4, max=10.0)
    odom_sigma_xy_per_m: float = param(
        0.05, 'Additional odometry translation noise per metre travelled (m/m).',
        min=0.0, max=1.0)
    odom_sigma_theta: float = param(
        0.0087, 'Odometry increment rotation noise per scan step (rad, 1 sigma; 0.5 deg).',
        min=1e-5, max=3.0)
    odom_sigma_theta_per_m: float = param(
        0.0, 'Additional odometry rotation noise per metre travelled (rad/m).',
        min=0.0, max=1.0)
    odom_sigma_theta_per_rad: float = param(
        0.05, 'Additional odometry rotation noise per radian turned (rad/rad).',
        min=0.0, max=1.0)
    # --- motion-model prior (no odometry)
    cv_sigma_xy: float = param(
        0.05, 'Without usable odometry the prediction is the previous motion scaled to the '
        'time step (constant velocity); its noise per scan step, each of x and y (m, 1 '
        'sigma); with adaptive_prior: the starting value, then adapted.', min=1e-4, max=10.0)
    cv_sigma_theta: float = param(
        0.05, 'Constant-velocity prediction rotation noise per scan step (rad, 1 sigma).',
        min=1e-5, max=3.0)
    # --- adaptive prior
    adaptive_prior: bool = param(
        True, 'Adapt the odometry and constant-velocity noise online to how well they agree '
        'with the accepted ICP matches (variance per step, per metre and per radian, '
        'robust running least squares): the same defaults for good and poor odometry. '
        'false = the fixed odom_sigma_* / cv_sigma_* model.')
    adaptive_memory: int = param(
        50, 'Effective number of recent matches the adapted noise is estimated from '
        '(exponential forgetting).', min=2, max=100000)
    adaptive_weight: float = param(
        5.0, 'Weight of the fixed odom_sigma_* / cv_sigma_* model in the adapted noise, in '
        'matches: it dominates the first few matches and regularises directions the data '
        'do not inform.', min=0.0, max=100000.0)
    adaptive_clip: float = param(
        3.0, 'A disagreement beyond this many predicted sigmas counts as this many (false '
        'matches and odometry glitches do not blow the estimate up).', min=1.0, max=100.0)
    prior_max_ratio: float = param(
        10.0, 'The prediction\'s information (odometry or constant velocity) is at most this '
        'multiple of the match\'s, along each of x, y and heading: a match always counts, so '
        'the adapted prior of a good odometry cannot silence the laser (0 = no bound).',
        min=0.0, max=1e6)
    prior_gate: float = param(
        5.0, 'A match that disagrees with the prediction by more than this many combined '
        'sigmas (Mahalanobis distance) overrides it: the prediction\'s weight falls with the '
        'square of the excess (a wheel slip shows). 0 = plain fusion.', min=0.0, max=1000.0)
    # --- platform limits
    max_translation_speed: float = param(
        2.0, 'Platform maximum speed (m/s): faster matches and odometry steps are rejected.',
        min=0.01, max=100.0)
    max_rotation_speed: float = param(
        _PI, 'Platform maximum turn rate (rad/s): faster matches and odometry steps are '
        'rejected.', min=0.01, max=100.0)
    # --- scan points
    min_range: float = param(0.05, 'Readings closer than this (m) are not used.',
                             min=0.0, max=10.0)
    max_range: float = param(40.0, 'Readings farther than this (m) are not used.',
                             min=0.5, max=1000.0)
    max_points: int = param(200, 'At most this many scan points (evenly thinned) are matched.',
                            min=10, max=100000)
    min_points: int = param(30, 'Fewer valid (or matched) points than this: no ICP.',
                            min=3, max=100000)
    # --- ICP
    map_scans: int = param(5, 'Scans in the local map the current scan is matched against.',
                           min=1, max=100)
    map_min_translation: float = param(
        0.05, 'A scan joins the local map only once the scanner has moved this far (m) or '
        'turned map_min_rotation since the last scan that joined: a standing scanner keeps '
        'matching the same key scans and its pose does not random-walk.', min=0.0, max=10.0)
    map_min_rotation: float = param(
        0.035, 'See map_min_translation (rad).', min=0.0, max=_PI)
    association_distance: float = param(
        1.0, 'First (coarsest) nearest-neighbour association distance (m).',
        min=0.01, max=10.0)
    association_distance_final: float = param(
        0.1, 'Last (finest) association distance (m); the levels between are geometric.',
        min=0.005, max=10.0)
    association_levels: int = param(3, 'Number of association distances, coarse to fine.',
                                    min=1, max=10)
    final_associations: int = param(2, 'Times the finest distance is re-associated.',
                                    min=1, max=10)
    coarse_stride: int = param(
        1, 'Use every n-th scan point at the coarser association distances (speed).',
        min=1, max=10)
    steps_per_association: int = param(3, 'Gauss-Newton steps per association (fewer when '
                                       'a step is below 0.1 mm and 0.006 deg).', min=1, max=10)
    kernel_ratio: float = param(
        0.3, 'Cauchy kernel scale as a fraction of the current association distance.',
        min=0.01, max=10.0)
    converged_translation: float = param(
        0.005, 'ICP has converged when its last step moved less than this (m) ...',
        min=1e-6, max=1.0)
    converged_rotation: float = param(
        0.002, '... and turned less than this (rad).', min=1e-6, max=1.0)
    normal_max_gap: float = param(
        0.3, 'Neighbouring scan points farther apart than this (m, plus 5 % of the range) '
        'are on different surfaces (normal estimation).', min=0.01, max=5.0)
    icp_model_sigma: float = param(
        0.01, 'Error of ICP along a direction constrained by every point (m); a direction '
        'constrained by a fraction f of the points gets sigma / sqrt(f). Weighs ICP against '
        'the odometry prior.', min=1e-4, max=1.0)
    degeneracy_threshold: float = param(
        0.01, 'A direction constrained by less than this fraction of the points is '
        'degenerate: odometry is used along it.', min=0.0, max=1.0)
    # --- acceptance
    min_inlier_ratio: float = param(
        0.3, 'Least fraction of scan points matched within the final distance.',
        min=0.0, max=1.0)
    max_rms: float = param(0.1, 'Largest weighted RMS point-to-line residual (m).',
                           min=0.001, max=10.0)
    max_correction_translation: float = param(
        0.5, 'Largest ICP correction of the odometry prediction (m); more is a false match.',
        min=0.01, max=100.0)
    max_correction_rotation: float = param(
        0.35, 'Largest ICP correction of the odometry prediction (rad).', min=0.001,
        max=_PI)
    max_lost_scans: int = param(
        5, 'After this many scans in a row without an accepted match (the platform coasting '
        'on its motion model) the local map is re-seeded from the current scan; the pose '
        'chain continues.', min=1, max=100000)
    speed_check_jitter: float = param(
        0.05, 'The platform speed checks allow the motion of the time step plus this (s): '
        'scan stamps jitter.', min=0.0, max=10.0)


@dataclass(frozen=True)
class EgoMotionEstimate:
    """The ego-motion result for one scan (see the module docstring for ``source``)."""

    stamp: float
    pose: np.ndarray            # (3,) scanner pose in the odometry frame (NaN: no pose)
    motion: np.ndarray          # (3,) relative motion since the previous posed scan (NaN: none)
    covariance: np.ndarray      # (3, 3) of ``motion`` (scanner-frame perturbation)
    source: str
    reason: str
    dt: float = 0.0             # time since the previous posed scan (s)
    odometry_motion: np.ndarray | None = None  # the odometry increment, when available
    n_points: int = 0           # scan points used
    inlier_ratio: float = 0.0   # ICP: fraction of points matched within the final distance
    rms: float = float('nan')   # ICP: weighted RMS residual (m)
    iterations: int = 0         # ICP: Gauss-Newton steps
    min_eigenvalue: float = float('nan')  # ICP: weakest normalised Hessian eigenvalue
    coasting: bool = False      # pose from the motion model (no match accepted)

    @property
    def ok(self) -> bool:
        """True when ``pose`` and ``motion`` are usable (a coasting estimate is, with its
        prediction's covariance; detection does not trust it)."""
        return self.source != SOURCE_NONE


# --------------------------------------------------------------------------- odometry


class OdometryBuffer:
    """Time-ordered odometry samples, interpolated on demand; robust to bad streams.

    Samples are split into *segments*: a jump (a step faster than the platform can move)
    starts a new one, and nothing is interpolated across segments. ``add`` returns None, or
    ``(kind, message)`` when the sample was not stored as is (kind: a fixed short label).
    """

    def __init__(self, config: EgoMotionConfig):
        self.config = config
        self.clear()

    @property
    def config(self) -> EgoMotionConfig:
        return self._config

    @config.setter
    def config(self, config: EgoMotionConfig) -> None:
        self._config = config
        mount = (config.mount_x, config.mount_y, config.mount_yaw)
        self._mount = np.array(mount, dtype=float) if any(mount) else None
        # a jump: a step faster than 1.5 times the platform's limits, plus 0.1 m or rad
        self._jump_xy = 1.5 * config.max_translation_speed
        self._jump_theta = 1.5 * config.max_rotation_speed

    def clear(self) -> None:
        self._t: list[float] = []
        self._p: list[tuple[float, float, float]] = []
        self._seg: list[int] = []
        self._segment = 0

    def __len__(self) -> int:
        return len(self._t)

    @property
    def newest(self) -> float | None:
        return self._t[-1] if self._t else None

    def add(self, stamp: float, pose) -> tuple[str, str] | None:
        """Store one sample (plain floats and lists: it runs for every odometry message)."""
        try:
            t = float(stamp)
            x, y, th = float(pose[0]), float(pose[1]), float(pose[2])
        except (TypeError, ValueError, IndexError):
            return 'bad odometry', 'odometry sample is not a time stamp and (x, y, theta)'
        if not (math.isfinite(t) and math.isfinite(x) and math.isfinite(y)
                and math.isfinite(th)):
            return 'bad odometry', 'non-finite odometry sample (ignored)'
        p = (x, y, wrap_scalar(th))
        ts = self._t
        if not ts or t > ts[-1]:
            reason = None
            if ts:
                q = self._p[-1]
                dt = t - ts[-1]
                dd = math.hypot(x - q[0], y - q[1])
                da = abs(wrap_scalar(p[2] - q[2]))
                if dd > self._jump_xy * dt + 0.1 or da > self._jump_theta * dt + 0.1:
                    self._segment += 1
                    reason = 'odometry jumped', (
                        f'odometry jumped {dd:.2f} m / {math.degrees(da):.1f} deg '
                        f'in {dt:.3f} s (faster than the platform): new segment')
            ts.append(t)
            self._p.append(p)
            self._seg.append(self._segment)
            if len(ts) > 200000:  # hard memory bound, whatever the query pattern
                del ts[:100000], self._p[:100000], self._seg[:100000]
            return reason
        if t == self._t[-1] or t in self._t[max(0, len(self._t) - 8):]:
            return 'odometry duplicate', 'duplicate odometry stamp (ignored)'
        if self._t[-1] - t > self.config.odom_reset_threshold:
            newest = self._t[-1]
            self.clear()
            self._t.append(t)
            self._p.append(p)
            self._seg.append(self._segment)
            return 'odometry restart', (f'odometry went back in time {newest - t:.3f} s '
                                        f'(restart?): buffer cleared')
        i = bisect.bisect_left(self._t, t)
        if i == 0:
            return 'odometry too old', 'odometry sample older than the buffer (ignored)'
        seg = self._seg[i - 1]
        self._t.insert(i, t)
        self._p.insert(i, p)
        self._seg.insert(i, seg)
        return 'odometry out of order', 'odometry out of order (inserted in time order)'

    def trim(self, before: float) -> None:
        """Forget samples older than ``before`` (keeping one for interpolation)."""
        i = bisect.bisect_left(self._t, before) - 1
        if i > 64:
            del self._t[:i], self._p[:i], self._seg[:i]

    def scanner_pose(self, t: float) -> tuple[np.ndarray | None, int, str]:
        """:meth:`pose_at` for a scan stamped ``t``: read at ``t + odom_latency``, with the
        scanner's mounting applied; samples older than ``odom_buffer`` are forgotten."""
        c = self.config
        odo, seg, reason = self.pose_at(t + c.odom_latency)
        if odo is not None:
            self.trim(t + c.odom_latency - c.odom_buffer)
            if self._mount is not None:
                odo = compose(odo, self._mount)
        return odo, seg, reason

    def pose_at(self, t: float) -> tuple[np.ndarray | None, int, str]:
        """``(pose, segment, '')`` at time ``t``, or ``(None, -1, reason)``."""
        c = self.config
        ts = self._t
        if not ts:
            return None, -1, 'no odometry received'
        if t > ts[-1]:
            late = t - ts[-1]
            if late > c.odom_max_extrapolation:
                return None, -1, f'odometry late: newest sample {late:.3f} s before the scan'
            p1 = self._p[-1]
            if len(ts) >= 2 and self._seg[-2] == self._seg[-1] and \
                    ts[-1] - ts[-2] <= c.odom_max_gap:
                p0, dt0 = self._p[-2], ts[-1] - ts[-2]
                f = late / dt0
                guess = np.array([p1[0] + (p1[0] - p0[0]) * f, p1[1] + (p1[1] - p0[1]) * f,
                                  wrap_scalar(p1[2] + wrap_scalar(p1[2] - p0[2]) * f)])
                return guess, self._seg[-1], ''
            return np.array(p1), self._seg[-1], ''
        if t < ts[0]:
            return None, -1, f'no odometry before the scan (first sample {ts[0] - t:.3f} s later)'
        i = bisect.bisect_left(ts, t)
        if ts[i] == t:
            return np.array(self._p[i]), self._seg[i], ''
        t0, t1 = ts[i - 1], ts[i]
        if self._seg[i - 1] != self._seg[i]:
            return None, -1, 'odometry jumped at the scan time'
        if t1 - t0 > c.odom_max_gap:
            return None, -1, f'odometry gap of {t1 - t0:.3f} s around the scan'
        p0, p1 = self._p[i - 1], self._p[i]
        f = (t - t0) / (t1 - t0)
        return np.array([p0[0] + (p1[0] - p0[0]) * f, p0[1] + (p1[1] - p0[1]) * f,
                         wrap_scalar(p0[2] + wrap_scalar(p1[2] - p0[2]) * f)]), self._seg[i], ''


# ------------------------------------------------------------------- adaptive prior


class AdaptiveNoise:
    """Running estimate of a motion prediction's noise from its disagreement with ICP.

    Model, for a predicted motion of distance ``d`` and angle ``a``: the variance of each of
    x and y is ``cx . f`` and that of the heading ``ct . f`` with ``f = (1, d^2, a^2)``
    (noise per step, per metre, per radian). Every accepted, fully constrained match gives a
    disagreement ``e`` between the prediction and the ICP motion; ``e^2`` minus the ICP's own
    variance is an unbiased sample of the prediction's variance. The coefficients are the
    least-squares fit to these samples with exponential forgetting (``memory`` samples),
    regularised towards the fixed model ``c0`` with the weight of ``weight`` samples, and
    kept non-negative; a sample beyond ``clip`` predicted sigmas is clipped there (a false
    match must not blow the estimate up; a real change passes in a few steps since each
    clipped sample still raises the estimate). One kernel call per update
    (:func:`_update_noise`); ``coef`` is kept as plain floats for the per-scan prediction.
    """

    def __init__(self, cx0, ct0, memory: int, weight: float, clip: float):
        self.c0 = (tuple(float(v) for v in cx0), tuple(float(v) for v in ct0))
        self.coef = self.c0
        self.forget = 1.0 - 1.0 / max(float(memory), 1.0)
        self.weight = float(weight)
        self.clip2 = float(clip) ** 2
        # the running sums: Gram matrix of f, right-hand sides (x, theta), sum of f^2, count
        self._gram = np.zeros((3, 3))
        self._rhs = np.zeros((2, 3))
        self._f2 = np.zeros(3)
        self._count = np.zeros(1)
        self._c0 = np.array(self.c0)
        self._coef = self._c0.copy()
        self._settings = np.array([self.forget, self.weight, self.clip2])
        jit.compiled('ego-motion kernels (fusion, adaptive prior)', _exercise_kernels)

    @property
    def count(self) -> float:
        """Effective number of matches learnt from (forgetting included)."""
        return float(self._count[0])

    def variance(self, motion) -> tuple[float, float]:
        """``(var_xy, var_theta)`` of a prediction ``motion`` (x, y, theta)."""
        m = plain_floats(motion)
        d2 = float(m[0] * m[0] + m[1] * m[1])
        a2 = float(m[2] * m[2])
        cx, ct = self.coef
        return (max(cx[0] + cx[1] * d2 + cx[2] * a2, 1e-10),
                max(ct[0] + ct[1] * d2 + ct[2] * a2, 1e-12))

    def information(self, motion) -> np.ndarray:
        """The diagonal (x, y, theta) of the information of a prediction ``motion``."""
        vxy, vth = self.variance(motion)
        return np.array([1.0 / vxy, 1.0 / vxy, 1.0 / vth])

    def update(self, motion, error, icp_variance) -> None:
        """One disagreement ``error`` (x, y, theta) of the prediction ``motion`` with an ICP
        motion of variance ``icp_variance`` (x, y, theta)."""
        m, e = plain_floats(motion), plain_floats(error)
        _update_noise(float(m[0]), float(m[1]), float(m[2]), float(e[0]), float(e[1]),
                      float(e[2]),
                      float(icp_variance[0]), float(icp_variance[1]), float(icp_variance[2]),
                      self._settings, self._gram, self._rhs, self._f2, self._count, self._c0,
                      self._coef)
        cx, ct = self._coef.tolist()
        self.coef = (tuple(cx), tuple(ct))


@jit.kernel
def _update_noise(m0, m1, m2, e0, e1, e2, iv0, iv1, iv2, settings, gram, rhs, f2, count,
                  c0, coef):
    """:meth:`AdaptiveNoise.update` in place on its sums and ``coef``: the sample of the
    prediction ``m`` (disagreement ``e``, ICP variance ``iv``) added with forgetting, and the
    coefficients solved again."""
    forget, weight, clip2 = settings[0], settings[1], settings[2]
    d2 = m0 * m0 + m1 * m1
    a2 = m2 * m2
    vxy = _at_least(coef[0, 0] + coef[0, 1] * d2 + coef[0, 2] * a2, 1e-10)
    vth = _at_least(coef[1, 0] + coef[1, 1] * d2 + coef[1, 2] * a2, 1e-12)
    ix = 0.5 * (iv0 + iv1)
    ex2 = _at_most(0.5 * (e0 * e0 + e1 * e1), clip2 * (vxy + ix)) - ix
    et2 = _at_most(e2 * e2, clip2 * (vth + iv2)) - iv2
    g = forget
    f = (1.0, d2, a2)
    for i in range(3):             # (f[0] = 1: its products are exactly the other factor)
        for j in range(i, 3):
            gram[i, j] = g * gram[i, j] + f[i] * f[j]
            gram[j, i] = gram[i, j]
        rhs[0, i] = g * rhs[0, i] + f[i] * ex2
        rhs[1, i] = g * rhs[1, i] + f[i] * et2
        f2[i] = g * f2[i] + f[i] * f[i]
    count[0] = g * count[0] + 1.0
    # the ridge weights: the fixed model counts as ``weight`` samples of each f^2
    n = _at_least(count[0], 1e-12)
    pen = np.empty(3)
    for i in range(3):
        pen[i] = weight * f2[i] / n
    top = _at_least(_at_least(pen[0], pen[1]), pen[2]) + 1e-300
    for i in range(3):
        pen[i] = pen[i] + 1e-9 * top
    for k in range(2):
        _nonnegative_ridge(gram, rhs[k], pen, c0[k], coef[k])


@jit.inline
def _at_least(value, bound):
    """Python's ``max(value, bound)``: ``value`` unless ``bound`` is larger (NaN stays)."""
    return bound if bound > value else value


@jit.inline
def _at_most(value, bound):
    """Python's ``min(value, bound)``: ``value`` unless ``bound`` is smaller (NaN stays)."""
    return bound if bound < value else value


@jit.inline
def _nonnegative_ridge(gram, rhs, pen, c0, out):
    """``argmin |G c - r|`` ridge-regularised towards ``c0`` (weights ``pen``), c >= 0, into
    ``out``: the normal equations on the free coefficients, dropping negative ones."""
    a = gram.copy()
    b = np.empty(3)
    for i in range(3):
        a[i, i] = gram[i, i] + pen[i]
        b[i] = rhs[i] + pen[i] * c0[i]
    free = np.arange(3)
    n_free = 3
    sol = np.empty(3)
    while n_free:
        if not _solve_small(a, b, free, n_free, sol):
            out[:] = c0
            return
        if np.all(sol[:n_free] >= 0.0):
            out[:] = 0.0
            for k in range(n_free):
                out[free[k]] = sol[k]
            return
        kept = 0
        for k in range(n_free):
            if sol[k] > 0.0:
                free[kept] = free[k]
                kept += 1
        n_free = kept
    out[:] = 0.0


@jit.inline
def _solve_small(a, b, rows, n, out):
    """Solve the system of ``a`` and ``b`` restricted to ``rows[:n]`` (n = 1, 2 or 3) by
    Cramer's rule into ``out[:n]``; False when singular."""
    if n == 1:
        i = rows[0]
        if not a[i, i] > 0.0:
            return False
        out[0] = b[i] / a[i, i]
        return True
    if n == 2:
        i, j = rows[0], rows[1]
        det = a[i, i] * a[j, j] - a[i, j] * a[j, i]
        if abs(det) < 1e-300:
            return False
        out[0] = (b[i] * a[j, j] - a[i, j] * b[j]) / det
        out[1] = (a[i, i] * b[j] - b[i] * a[j, i]) / det
        return True
    return _cramer3(a[0, 0], a[0, 1], a[0, 2], a[1, 0], a[1, 1], a[1, 2], a[2, 0], a[2, 1],
                    a[2, 2], b[0], b[1], b[2], out)


@jit.inline
def _cramer3(p, q, r, s, t, u, v, w, x, b0, b1, b2, out):
    """The 3x3 system ``[[p, q, r], [s, t, u], [v, w, x]] y = b`` by Cramer's rule into
    ``out``; False when singular."""
    det = p * (t * x - u * w) - q * (s * x - u * v) + r * (s * w - t * v)
    if abs(det) < 1e-300:
        return False
    out[0] = (b0 * (t * x - u * w) - q * (b1 * x - u * b2) + r * (b1 * w - t * b2)) / det
    out[1] = (p * (b1 * x - u * b2) - b0 * (s * x - u * v) + r * (s * b2 - b1 * v)) / det
    out[2] = (p * (t * b2 - b1 * w) - q * (s * b2 - b1 * v) + b0 * (s * w - t * v)) / det
    return True


# ------------------------------------------------------------------------ prediction


def too_fast(motion, dt: float, config: EgoMotionConfig) -> str:
    """Why ``motion`` over ``dt`` seconds is beyond the platform's limits ('' if it is not);
    scan stamps jitter, so the step may take ``speed_check_jitter`` longer."""
    if dt <= 0.0:
        return ''
    x, y, theta = plain_floats(motion)
    span = dt + config.speed_check_jitter
    v = math.hypot(x, y) / span
    w = abs(theta) / span
    if v > config.max_translation_speed:
        return f'{v:.2f} m/s > {config.max_translation_speed:g} m/s'
    if w > config.max_rotation_speed:
        return (f'{math.degrees(w):.0f} deg/s > '
                f'{math.degrees(config.max_rotation_speed):.0f} deg/s')
    return ''


def odometry_increment(previous, current, dt: float,
                       config: EgoMotionConfig) -> tuple[np.ndarray | None, str]:
    """``(increment, '')``: the odometry motion between two scans' ``(pose, segment)``
    (``current`` also has the reason it may be missing), or ``(None, why not)``."""
    odo, seg, missing = current
    if odo is None:
        return None, missing
    if previous[0] is None:
        return None, 'no odometry at the previous scan'
    if seg != previous[1]:
        return None, 'odometry jumped since the previous scan'
    inc = between(previous[0], odo)
    speed = too_fast(inc, dt, config)
    if speed:
        return None, f'odometry step implies {speed} (jump?)'
    return inc, ''


@dataclass(frozen=True)
class Prediction:
    """The motion expected since the previous scan (previous scanner frame) and its prior."""

    motion: np.ndarray             # the odometry increment, else the constant-velocity guess
    information: np.ndarray        # the prior's information, diagonal (x, y, theta)
    odometry: np.ndarray | None    # the odometry increment (None: not usable)
    constant_velocity: np.ndarray  # the previous motion scaled to the time step


class MotionPrior:
    """Step 1 and 2 of the method: the prediction and its noise, fixed (``odom_sigma_*``,
    ``cv_sigma_*``) or adapted to the accepted matches (``adaptive_prior``)."""

    def __init__(self, config: EgoMotionConfig):
        c = self.config = config
        self.odometry_noise = AdaptiveNoise(
            (c.odom_sigma_xy ** 2, c.odom_sigma_xy_per_m ** 2, 0.0),
            (c.odom_sigma_theta ** 2, c.odom_sigma_theta_per_m ** 2,
             c.odom_sigma_theta_per_rad ** 2),
            c.adaptive_memory, c.adaptive_weight, c.adaptive_clip)
        self.motion_model_noise = AdaptiveNoise(
            (c.cv_sigma_xy ** 2, 0.0, 0.0), (c.cv_sigma_theta ** 2, 0.0, 0.0),
            c.adaptive_memory, c.adaptive_weight, c.adaptive_clip)
        self._odometry_model = ((c.odom_sigma_xy, c.odom_sigma_xy_per_m, 0.0),
                                (c.odom_sigma_theta, c.odom_sigma_theta_per_m,
                                 c.odom_sigma_theta_per_rad))
        self._motion_model = (c.cv_sigma_xy, 0.0, 0.0), (c.cv_sigma_theta, 0.0, 0.0)
        # no motion seen yet: the guess (standing) is weak
        self._unknown = np.array([0.01 / c.cv_sigma_xy ** 2, 0.01 / c.cv_sigma_xy ** 2,
                                  0.01 / c.cv_sigma_theta ** 2])

    def predict(self, increment, last_motion, last_dt: float, dt: float) -> Prediction:
        """The odometry ``increment`` when usable, else the ``last_motion`` (over ``last_dt``)
        scaled to ``dt`` (constant velocity, at most 3 times)."""
        if last_motion is None or last_dt <= 0.0:
            cv = np.zeros(3)
        else:
            cv = last_motion * min(dt / last_dt, 3.0)
        if increment is not None:
            info = self._information(self.odometry_noise, increment, self._odometry_model)
            return Prediction(increment, info, increment, cv)
        if last_motion is None:
            return Prediction(cv, self._unknown, None, cv)
        info = self._information(self.motion_model_noise, cv, self._motion_model)
        return Prediction(cv, info, None, cv)

    def learn(self, prediction: Prediction, icp_motion, icp_information,
              has_history: bool) -> None:
        """Feed the disagreement of the prediction with an accepted, fully constrained ICP
        motion (before fusion); the motion model is learnt only once a motion was seen."""
        var = _inverse_diagonal(icp_information)
        if var is None:
            return
        inc = prediction.odometry
        if inc is not None:
            self.odometry_noise.update(inc, between(inc, icp_motion), var)
        elif has_history:
            cv = prediction.constant_velocity
            self.motion_model_noise.update(cv, between(cv, icp_motion), var)

    def _information(self, noise: AdaptiveNoise, motion, fixed) -> np.ndarray:
        """Information (diagonal, x y theta) of a prediction ``motion``: the adapted noise,
        or the fixed model (sigma = per step + per metre * d + per radian * |a|)."""
        if self.config.adaptive_prior:
            return noise.information(motion)
        (a, b, _), (ta, tb, tc) = fixed
        d = math.hypot(motion[0], motion[1])
        sxy = a + b * d
        sth = ta + tb * d + tc * abs(motion[2])
        return np.array([1.0 / sxy ** 2, 1.0 / sxy ** 2, 1.0 / sth ** 2])


# ----------------------------------------------------------------------------- match


class ScanMatcher:
    """Step 3: the scan's points matched against the local map of the last key scans
    (one compiled kernel per scan, :mod:`laser_tracker.core.icp`)."""

    def __init__(self, config: EgoMotionConfig):
        c = self.config = config
        hi, lo, n = c.association_distance, c.association_distance_final, c.association_levels
        distances = (lo,) if n == 1 or hi <= lo else \
            tuple(float(v) for v in np.geomspace(hi, lo, n))
        self.schedule = icp.Schedule.of(
            distances, c.kernel_ratio, c.steps_per_association, c.final_associations,
            converged_translation=c.converged_translation,
            converged_rotation=c.converged_rotation, coarse_stride=c.coarse_stride)
        self.map = icp.LocalMap(c.map_scans, c.normal_max_gap)
        self.key_pose: np.ndarray | None = None
        #: the checks and the fusion's settings, as :func:`_match_and_fuse` reads them
        self.checks = np.array([c.min_points, c.min_inlier_ratio, c.max_rms,
                                c.degeneracy_threshold, c.icp_model_sigma ** 2,
                                c.prior_max_ratio, c.prior_gate, c.prior_gate ** 2, 2.0])
        icp.warm_up()
        jit.compiled('ego-motion kernels (match and fusion)', _exercise_match_and_fuse)

    def clear(self) -> None:
        self.map.clear()
        self.key_pose = None

    def match(self, scan: Scan, pose0=None,
              skip: np.ndarray | None = None) -> tuple[np.ndarray, icp.IcpResult | None]:
        """The scan's valid points (``Scan.valid()`` within ``min_range``/``max_range``, at
        most ``max_points``, without the beams ``skip`` leaves out) and their ICP result
        from ``pose0`` (None: not matched, or too few points or map points)."""
        c = self.config
        _, cos, sin = beam_table(float(scan.angle_min), float(scan.angle_increment),
                                 scan.n_beams)
        return icp.match_scan(scan.ranges, cos, sin, max(scan.range_min, 1e-6),
                              scan.range_max, c.min_range, c.max_range, c.max_points,
                              c.min_points, self.map, pose0, self.schedule, skip)

    def match_and_fuse(self, scan: Scan, predicted: np.ndarray, previous: np.ndarray,
                       prior: np.ndarray, skip: np.ndarray | None = None):
        """Steps 3-4 in one kernel call (:func:`_match_and_fuse`): ``(points, ICP result or
        None, verdict, packed)``; with verdict ``FUSED`` the fusion is in ``packed``."""
        c = self.config
        _, cos, sin = beam_table(float(scan.angle_min), float(scan.angle_increment),
                                 scan.n_beams)
        pts, packed = _match_and_fuse(
            scan.ranges, icp.NO_SKIP if skip is None else skip, cos, sin,
            max(scan.range_min, 1e-6), scan.range_max, c.min_range, c.max_range,
            c.max_points, c.min_points, predicted, self.schedule.distances,
            self.schedule.settings, *self.map.arrays, previous, prior, self.checks)
        verdict = int(packed[_VERDICT])
        res = None if verdict == UNMATCHED else icp.result(packed, pts.shape[0])
        return pts, res, verdict, packed

    def unmatchable(self, n_points: int) -> str:
        """Why a scan of ``n_points`` points is not matched ('' if it is)."""
        c = self.config
        if n_points < c.min_points:
            return f'too few valid points ({n_points} < {c.min_points})'
        if self.map.n_points < c.min_points:
            return f'local map too small ({self.map.n_points} points)'
        return ''

    def refusal(self, res: icp.IcpResult, verdict: int) -> str:
        """Why the match ``res`` is refused, by its ``verdict`` (:func:`_verdict`)."""
        c = self.config
        if verdict == FEW_INLIERS:
            return f'only {res.n_inliers} points matched'
        if verdict == LOW_OVERLAP:
            return f'overlap {100 * res.inlier_ratio:.0f} % < {100 * c.min_inlier_ratio:.0f} %'
        if verdict == HIGH_RESIDUAL:
            return f'residual {res.rms:.3f} m > {c.max_rms:g} m'
        if verdict == NOT_CONVERGED:
            return 'did not converge'
        if verdict == NOT_FINITE:
            return 'non-finite result'
        if verdict == DEGENERATE:
            return 'degenerate in every direction'
        return ''

    def moved_since_key_scan(self, pose) -> bool:
        key = self.key_pose
        if key is None:
            return True
        d = between(key, pose)
        return (math.hypot(d[0], d[1]) >= self.config.map_min_translation
                or abs(d[2]) >= self.config.map_min_rotation)

    def add_key_scan(self, pose, pts: np.ndarray) -> None:
        """The scan at ``pose`` joins the local map (a scan of fewer than 2 points does not)."""
        if pts.shape[0] < 2:
            return
        self.map.add_scan(pose, pts)
        self.key_pose = pose.copy()


# ---------------------------------------------------------------------------- fusion


@dataclass(frozen=True)
class Fused:
    """Step 4: the ICP pose fused with the prediction."""

    pose: np.ndarray                # scanner pose in the odometry frame
    motion: np.ndarray              # since the previous scan (previous scanner frame)
    information: np.ndarray         # ICP's information (none along degenerate directions)
    prior: np.ndarray               # the prediction's information used (bounded, gated)
    degenerate: int                 # directions that took the prediction
    covariance: np.ndarray          # of the fused motion: (information + prior)^-1


def fuse(res: icp.IcpResult, packed: np.ndarray, previous, predicted,
         config: EgoMotionConfig) -> Fused:
    """The ICP pose fused with the ``predicted`` pose by information (the algebra was done
    by :func:`_match_and_fuse`, into ``packed``; the motion is from the ``previous`` pose).
    Along degenerate directions the prediction is kept."""
    c = config
    n_deg = int(packed[_N_DEG])
    pose = packed[_F_POSE:_F_POSE + 3]
    info = packed[_F_INFO:_F_INFO + 9].reshape(3, 3)
    lam = packed[_F_PRIOR:_F_PRIOR + 3]
    if not n_deg:
        return Fused(pose, packed[_F_MOTION:_F_MOTION + 3], info, lam, 0,
                     packed[_F_COV:_F_COV + 9].reshape(3, 3))
    # along degenerate directions (scaled coordinates z = delta / sv): the prediction
    deg = res.eigenvalues < c.degeneracy_threshold
    sv = np.array([1.0, 1.0, 1.0 / res.scale])
    z = between(predicted, pose) / sv
    u = res.eigenvectors[:, ~deg]
    pose = compose(predicted, sv * (u @ (u.T @ z)))
    # no ICP information along them
    v = res.eigenvectors[:, deg]
    proj = np.eye(3) - v @ v.T
    s_inv = np.diag(1.0 / sv)
    info = s_inv @ proj @ np.diag(sv) @ info @ np.diag(sv) @ proj @ s_inv
    return Fused(pose, between(previous, pose), info, lam, n_deg, _covariance(info, lam))


def implausible(motion, predicted, pose, odometry, dt: float, config: EgoMotionConfig) -> str:
    """Step 5, the fused match's checks: the platform's speed limits and, with odometry, the
    correction of the ``predicted`` pose ('' when it passes)."""
    c = config
    speed = too_fast(motion, dt, c)
    if speed:
        return f'match implies {speed}'
    if odometry is not None:
        cx, cy, ct = between(predicted, pose).tolist()
        dist = math.hypot(cx, cy)
        if dist > c.max_correction_translation or abs(ct) > c.max_correction_rotation:
            return (f'match disagrees with odometry by {dist:.2f} m / '
                    f'{math.degrees(abs(ct)):.1f} deg')
    return ''


def _inverse_diagonal(m):
    """Diagonal of the inverse of a symmetric positive 3x3 matrix (None when singular)."""
    (a, b, c), (_, d, e), (_, _, f) = m.tolist()
    ca, cd, cf = d * f - e * e, a * f - c * c, a * d - b * b
    det = a * ca + b * (c * e - b * f) + c * (b * e - c * d)
    if not det > 0.0:
        return None
    return (ca / det, cd / det, cf / det)


# ------------------------------------------------------------------ the fusion's kernels
#
# The arithmetic of the numpy formulation they replaced, operation for operation (results
# equal bit for bit): Python's ``x ** 2`` is libm's pow, not always ``x * x``, so the gate's
# square is taken with a run-time exponent (``settings[4]`` = 2), which the compiler keeps a
# pow call; numpy's 3x3 solve and inverse are LAPACK's dgesv, as numba's np.linalg.solve.


@jit.kernel
def _fuse(icp_pose, hessian, sum_weights, n_deg, previous, predicted, prior, settings):
    """:func:`fuse`'s algebra: ``(pose, motion, information, prior used, covariance)``.
    ICP's information ``H / (sum w * model_sigma^2)``; with no degenerate direction the
    prior's information bounded by ``prior_max_ratio`` times ICP's and gated
    (``prior_gate``); the fused pose one information-weighted step from the ICP pose
    towards the prediction. With degenerate directions (``n_deg`` > 0) the motion and the
    covariance are left to the caller (NaN), which projects them out first."""
    sigma2, max_ratio, gate, gate2, power = (settings[0], settings[1], settings[2],
                                             settings[3], settings[4])
    info = hessian / (_at_least(sum_weights, 1e-12) * sigma2)
    d = _between(icp_pose, predicted)
    lam = prior.copy()
    if n_deg == 0:
        if max_ratio > 0.0:
            for k in range(3):
                bound = max_ratio * info[k, k]
                if bound < lam[k] or math.isnan(bound):      # np.minimum
                    lam[k] = bound
        if gate > 0.0:
            # a converged, well-overlapping match far outside the prediction's noise: the
            # prediction is what failed (a wheel slip): it stops counting
            m2 = _mahalanobis2(info, lam, d)
            if m2 > gate2:
                lam = lam * (gate2 / m2) ** power
    pose = _compose(icp_pose, np.linalg.solve(info + np.diag(lam), lam * d))
    if n_deg:
        return pose, np.full(3, np.nan), info, lam, np.full((3, 3), np.nan)
    return pose, _between(previous, pose), info, lam, _covariance(info, lam)


#: Verdicts of a match (:func:`_verdict`): fused, not matched (too few scan or map
#: points), and the reasons for refusing it.
FUSED, UNMATCHED, FEW_INLIERS, LOW_OVERLAP, HIGH_RESIDUAL, NOT_CONVERGED, NOT_FINITE, \
    DEGENERATE = range(8)
#: Layout of :func:`_match_and_fuse`'s packed result after the match's (``icp.result``):
#: the verdict, the degenerate directions, and the fusion (pose, motion, information,
#: prior used, covariance).
_VERDICT = icp.RESULT_SIZE
_N_DEG, _F_POSE, _F_MOTION, _F_INFO, _F_PRIOR, _F_COV, _PACKED = \
    _VERDICT + 1, _VERDICT + 2, _VERDICT + 5, _VERDICT + 8, _VERDICT + 17, _VERDICT + 20, \
    _VERDICT + 29


@jit.kernel
def _match_and_fuse(ranges, skip, cos, sin, valid_min, valid_max, min_range, max_range,
                    max_points, min_points, predicted, schedule, icp_settings, rows,
                    grid_rows, order, start, grid, previous, prior, checks):
    """Steps 3-4 for one scan: its points, their ICP match from the ``predicted`` pose, the
    checks of the match (:func:`_verdict`) and, when it passes them, its fusion with the
    prediction (information ``prior``; :func:`_fuse`). Returns the points and the packed
    result (``icp.result``'s layout, then ``_VERDICT`` ... ``_F_COV``; NaN where not
    computed)."""
    out = np.full(_PACKED, np.nan)
    pts, matched = icp._points_and_align(
        ranges, skip, cos, sin, valid_min, valid_max, min_range, max_range, max_points,
        min_points, predicted, schedule.shape[0], schedule, icp_settings, rows, grid_rows,
        order, start, grid, out)
    verdict, n_deg = _verdict(out, matched, pts.shape[0], checks)
    out[_VERDICT] = verdict
    out[_N_DEG] = n_deg
    if verdict == FUSED:
        icp_pose = out[icp.POSE:icp.POSE + 3].copy()
        hessian = out[icp.HESSIAN:icp.HESSIAN + 9].copy().reshape(3, 3)
        pose, motion, info, lam, cov = _fuse(icp_pose, hessian, out[icp._SUM_W], n_deg,
                                             previous, predicted, prior, checks[4:])
        out[_F_POSE:_F_POSE + 3] = pose
        out[_F_MOTION:_F_MOTION + 3] = motion
        out[_F_INFO:_F_INFO + 9] = info.ravel()
        out[_F_PRIOR:_F_PRIOR + 3] = lam
        out[_F_COV:_F_COV + 9] = cov.ravel()
    return pts, out


@jit.inline
def _verdict(out, matched, n_source, checks):
    """``(verdict, degenerate directions)`` of a packed match: refused with too few inliers
    (``min_points``), too little overlap (``min_inlier_ratio``), too large a residual
    (``max_rms``), no convergence, a non-finite pose, or degenerate in every direction
    (``degeneracy_threshold``); else ``FUSED``."""
    if not matched:
        return UNMATCHED, 0
    n_in = out[icp._N_IN]
    rms = out[icp._RMS]
    if n_in < checks[0]:
        return FEW_INLIERS, 0
    if (n_in / n_source if n_source else 0.0) < checks[1]:
        return LOW_OVERLAP, 0
    if not math.isfinite(rms) or rms > checks[2]:
        return HIGH_RESIDUAL, 0
    if not out[icp._CONVERGED]:
        return NOT_CONVERGED, 0
    if not (math.isfinite(out[icp.POSE]) and math.isfinite(out[icp.POSE + 1])
            and math.isfinite(out[icp.POSE + 2])):
        return NOT_FINITE, 0
    limit = checks[3]
    n_deg = 0
    for k in range(3):
        n_deg += out[icp.EIGENVALUES + k] < limit
    if n_deg == 3:
        return DEGENERATE, 3
    return FUSED, n_deg


@jit.kernel
def _covariance(info, lam):
    """``(info + diag(lam))^-1``, symmetrised (the pseudo-inverse when singular)."""
    a = info + np.diag(lam)
    try:
        cov = np.linalg.solve(a, np.eye(3))
    except Exception:  # noqa: BLE001 - numba catches no narrower class
        cov = np.linalg.pinv(a)
    return 0.5 * (cov + cov.T)


@jit.inline
def _mahalanobis2(info, lam, d):
    """``d^T (info^-1 + diag(lam)^-1)^-1 d`` for a symmetric 3x3 ``info``; inf when
    ``info`` is singular."""
    a, b, c = info[0, 0], info[0, 1], info[0, 2]
    e, f, i = info[1, 1], info[1, 2], info[2, 2]
    ca, cb, cc = e * i - f * f, c * f - b * i, b * f - c * e
    det = a * ca + b * cb + c * cc
    if not det > 0.0:
        return math.inf
    s01, s12 = cb / det, (b * c - a * f) / det
    s02 = cc / det
    s00 = ca / det + 1.0 / lam[0]
    s11 = (a * i - c * c) / det + 1.0 / lam[1]
    s22 = (a * e - b * b) / det + 1.0 / lam[2]
    sol = np.empty(3)
    if not _cramer3(s00, s01, s02, s01, s11, s12, s02, s12, s22, d[0], d[1], d[2], sol):
        return math.inf
    return sol[0] * d[0] + sol[1] * d[1] + sol[2] * d[2]


@jit.inline
def _wrap(theta):
    """:func:`geometry.wrap_scalar`."""
    return (theta + math.pi) % (2.0 * math.pi) - math.pi


@jit.inline
def _compose(a, b):
    """:func:`geometry.compose`."""
    c, s = math.cos(a[2]), math.sin(a[2])
    out = np.empty(3)
    out[0] = a[0] + c * b[0] - s * b[1]
    out[1] = a[1] + s * b[0] + c * b[1]
    out[2] = _wrap(a[2] + b[2])
    return out


@jit.inline
def _between(a, b):
    """:func:`geometry.between`."""
    c, s = math.cos(a[2]), math.sin(a[2])
    dx, dy = b[0] - a[0], b[1] - a[1]
    out = np.empty(3)
    out[0] = c * dx + s * dy
    out[1] = -s * dx + c * dy
    out[2] = _wrap(b[2] - a[2])
    return out


def _exercise_kernels() -> None:
    """The fusion's and the adaptive prior's kernels compiled (or loaded) for the argument
    types of real scans."""
    h = np.diag([4.0, 4.0, 1.0])
    z3 = np.zeros(3)
    one = np.ones(3)
    settings = np.array([1e-4, 10.0, 5.0, 25.0, 2.0])
    for n_deg in (0, 1):
        _fuse(z3, h, 1.0, n_deg, z3, np.array([0.1, 0.0, 0.01]), one, settings)
    _covariance(h, one)
    _update_noise(0.1, 0.0, 0.01, 0.01, 0.0, 0.001, 1e-5, 1e-5, 1e-7,
                  np.array([0.98, 5.0, 9.0]), np.zeros((3, 3)), np.zeros((2, 3)), z3.copy(),
                  np.zeros(1), np.full((2, 3), 1e-4), np.full((2, 3), 1e-4))


def _exercise_match_and_fuse() -> None:
    """:func:`_match_and_fuse` compiled (or loaded) for the argument types of real scans."""
    matcher = ScanMatcher(EgoMotionConfig(min_points=3))
    _, cos, sin = beam_table(-1.5, 0.075, 41)
    ranges = 2.0 + 0.1 * np.cos(3.0 * np.arange(41) * 0.075)
    scan = Scan(stamp=0.0, ranges=ranges, angle_min=-1.5, angle_increment=0.075,
                range_min=0.0, range_max=10.0)
    pts, _ = matcher.match(scan)
    matcher.add_key_scan(np.zeros(3), pts)
    for skip in (None, np.zeros(41, np.bool_)):
        matcher.match_and_fuse(scan, np.zeros(3), np.zeros(3), np.ones(3), skip)


# -------------------------------------------------------------------------- estimator


class EgoMotionEstimator:
    """Odometry prior plus point-to-line ICP against a short local map (module docstring).

    Its roles: the odometry buffer (``odometry``), the prediction and its adaptive prior
    (``prior``), the match (``matcher``) and the fusion (:func:`fuse`); the estimator holds
    the pose chain.
    """

    def __init__(self, config: EgoMotionConfig | None = None):
        self.config = config or EgoMotionConfig()
        self.odometry = OdometryBuffer(self.config)
        self.prior = MotionPrior(self.config)
        self.matcher = ScanMatcher(self.config)
        self.stats: Counter = Counter()
        self._notes: Counter = Counter()
        self._reset_state()

    # ----------------------------------------------------------------- public API

    def add_odometry(self, stamp: float, pose) -> None:
        """Feed one odometry sample (platform pose ``x, y, theta`` in the odometry frame)."""
        note = self.odometry.add(stamp, pose)
        if note:
            self._note(*note)

    def reset(self, reason: str = 'reset requested') -> None:
        """Forget the local map and the pose chain (odometry history and the adapted noise
        are kept)."""
        self._note('reset', f'ego-motion reset: {reason}', level=logging.WARNING)
        self.stats['resets'] += 1
        self._reset_state()

    def update(self, scan: Scan, skip: np.ndarray | None = None) -> EgoMotionEstimate:
        """Estimate the motion for ``scan`` (the steps of the module docstring), without the
        beams ``skip`` (bool per beam, e.g. the robot's body) leaves out."""
        t = float(scan.stamp)
        if self._stamp is not None and t == self._stamp:
            return self._none(t, 'scan stamp equals the previous one (skipped)')
        if self._stamp is not None and t < self._stamp:
            self.reset(f'time went backwards ({self._stamp:.3f} -> {t:.3f} s)')
        odo = self.odometry.scanner_pose(t)
        if self._pose is None:
            return self._init(t, self.matcher.match(scan, None, skip)[0], odo)
        dt = t - self._stamp
        # 1-2. the prediction: the odometry increment or constant velocity, and its prior
        inc, no_inc = odometry_increment(self._odo, odo, dt, self.config)
        if inc is None:
            self._note('no odometry', f'scan at {t:.3f} s: no odometry increment '
                       f'({no_inc}): constant-velocity prediction')
        pred = self.prior.predict(inc, self._motion, self._dt, dt)
        predicted = compose(self._pose, pred.motion)
        # 3-4. the match from the predicted pose, fused with the prediction when it passes
        # the checks (one kernel call); 5. the fused motion's checks
        pts, res, verdict, packed = self.matcher.match_and_fuse(
            scan, predicted, self._pose, pred.information, skip)
        fused, why = self._fuse(res, verdict, packed, pts.shape[0], pred, predicted, dt)
        if fused is not None:
            out, reseed = self._accepted(t, res, pred, fused, no_inc, pts.shape[0]), False
        else:
            out, reseed = self._coasting(t, res, pred, why, no_inc, pts.shape[0])
        self._advance(t, out, odo, dt, pts, reseed)
        return out

    # ------------------------------------------------------------------- internals

    def _fuse(self, res, verdict, packed, n_pts, pred, predicted,
              dt) -> tuple[Fused | None, str]:
        """``(fused, '')``, or ``(None, why the match is not used)``."""
        if verdict == UNMATCHED:
            return None, self.matcher.unmatchable(n_pts)
        if verdict != FUSED:
            return None, self.matcher.refusal(res, verdict)
        fused = fuse(res, packed, self._pose, predicted, self.config)
        why = implausible(fused.motion, predicted, fused.pose, pred.odometry, dt, self.config)
        return (None, why) if why else (fused, '')

    def _accepted(self, t, res, pred, fused, no_inc, n_pts) -> EgoMotionEstimate:
        """An accepted match: the fused motion; the prior learns from a full match."""
        if not fused.degenerate and self.config.adaptive_prior:
            self.prior.learn(pred, between(self._pose, res.pose), fused.information,
                             self._motion is not None)
        n_deg = fused.degenerate
        if n_deg and pred.odometry is not None:
            source, reason = SOURCE_PARTIAL, f'{n_deg} degenerate direction(s): odometry along them'
        elif n_deg:
            source = SOURCE_PARTIAL
            reason = (f'{n_deg} degenerate direction(s) and no odometry ({no_inc}): '
                      f'constant-velocity guess along them')
        else:
            source = SOURCE_ICP
            reason = 'icp' if pred.odometry is not None else f'icp without odometry ({no_inc})'
        self._lost = 0
        return self._estimate(t, fused.motion, fused.covariance, source, reason, pred, res,
                              n_pts)

    def _coasting(self, t, res, pred, why, no_inc, n_pts) -> tuple[EgoMotionEstimate, bool]:
        """No match: the platform coasts on its prediction; the pose chain goes on. After
        ``max_lost_scans`` such scans (or with no map to match against) the map is re-seeded
        from the scan (the second value)."""
        c = self.config
        if pred.odometry is not None:
            source, reason = SOURCE_ODOMETRY, f'ICP refused: {why}'
            self._note('icp refused', f'scan at {t:.3f} s: ICP refused ({why}): odometry used')
        else:
            source = SOURCE_CONSTANT_VELOCITY
            reason = f'ICP refused ({why}) and no odometry ({no_inc}): coasting'
            self._note('coasting', f'scan at {t:.3f} s: ICP refused ({why}) and no odometry '
                       f'({no_inc}): constant-velocity motion')
        map_ok = self.matcher.map.n_points >= c.min_points
        if res is not None or not map_ok:
            self._lost += 1  # a match was tried and refused, or there is nothing to match
        reseed = n_pts >= c.min_points and (not map_ok or self._lost >= c.max_lost_scans)
        if reseed:
            reason += '; local map re-seeded from this scan'
            self._note('map re-seeded', f'scan at {t:.3f} s: {self._lost} scans without a '
                       f'match: the local map is re-seeded from this scan (the pose chain '
                       f'continues)')
            self.stats['map re-seeded'] += 1
        return self._estimate(t, pred.motion, np.diag(1.0 / pred.information), source, reason,
                              pred, res, n_pts, coasting=True), reseed

    def _estimate(self, t, motion, cov, source, reason, pred, res, n_pts,
                  coasting=False) -> EgoMotionEstimate:
        diag = {}
        if res is not None:
            diag = dict(inlier_ratio=res.inlier_ratio, rms=res.rms, iterations=res.iterations,
                        min_eigenvalue=float(res.eigenvalues[0]))
        return EgoMotionEstimate(stamp=t, pose=compose(self._pose, motion), motion=motion,
                                 covariance=cov, source=source, reason=reason,
                                 dt=t - self._stamp, odometry_motion=pred.odometry,
                                 n_points=n_pts, coasting=coasting, **diag)

    def _advance(self, t, est: EgoMotionEstimate, odo, dt, pts, reseed: bool) -> None:
        """The pose chain moves on to the scan; the scan joins the local map when it was
        placed by ICP or odometry (a guess would pollute the map) and has moved since the
        last key scan, or re-seeds it."""
        self._pose = est.pose.copy()
        self._stamp = t
        self._odo = odo[:2] if odo[0] is not None else (None, -1)
        self._motion, self._dt = est.motion, dt
        if reseed:
            self.matcher.clear()
            self._lost = 0
            self.matcher.add_key_scan(self._pose, pts)
        elif est.source != SOURCE_CONSTANT_VELOCITY and \
                self.matcher.moved_since_key_scan(self._pose):
            self.matcher.add_key_scan(self._pose, pts)
        self.stats[est.source] += 1

    def _reset_state(self) -> None:
        self.matcher.clear()
        self._pose: np.ndarray | None = None
        self._stamp: float | None = None
        self._odo = (None, -1)              # odometry pose and segment of the previous scan
        self._motion: np.ndarray | None = None
        self._dt = 0.0
        self._lost = 0

    def _note(self, kind: str, message: str, level: int = logging.WARNING) -> None:
        """Log ``message``: first time, then at the 10th, 100th, ... time for its kind."""
        self._notes[kind] += 1
        self.stats[f'note: {kind}'] += 1
        n = self._notes[kind]
        if n == 1 or (n >= 10 and math.log10(n).is_integer()):
            log.log(level, '%s%s', message, f' ({n} times so far)' if n > 1 else '')
        else:
            log.debug('%s', message)

    def _init(self, t: float, pts: np.ndarray, odo) -> EgoMotionEstimate:
        self._reset_state()
        if odo[0] is not None:
            self._pose, reason = odo[0].copy(), 'first scan: pose from odometry'
            self._odo = odo[:2]
        else:
            self._pose, reason = np.zeros(3), f'first scan: pose at the origin ({odo[2]})'
        self._stamp = t
        self.matcher.add_key_scan(self._pose, pts)
        self.stats[SOURCE_INIT] += 1
        return EgoMotionEstimate(stamp=t, pose=self._pose.copy(), motion=np.zeros(3),
                                 covariance=np.zeros((3, 3)), source=SOURCE_INIT,
                                 reason=reason, n_points=pts.shape[0])

    def _none(self, t: float, reason: str) -> EgoMotionEstimate:
        self._note('no pose', f'scan at {t:.3f} s has no pose: {reason}')
        self.stats[SOURCE_NONE] += 1
        nan3 = np.full(3, np.nan)
        return EgoMotionEstimate(stamp=t, pose=nan3, motion=nan3.copy(),
                                 covariance=np.full((3, 3), np.nan), source=SOURCE_NONE,
                                 reason=reason)


# ---------------------------------------------------------------------------- offline


def estimate_track(scans: Iterable[Scan], odometry=None,
                   config: EgoMotionConfig | None = None) -> list[EgoMotionEstimate]:
    """Run the estimator over ``scans`` with ``odometry`` (a PoseTrack or ``(stamps, poses)``).

    Odometry samples are fed in time order, each before the first scan that could need it
    (stamp <= scan stamp + latency + max gap), as a live node would have received them.
    """
    est = EgoMotionEstimator(config)
    c = est.config
    if odometry is None:
        stamps, poses = np.zeros(0), np.zeros((0, 3))
    elif hasattr(odometry, 'stamps'):
        stamps, poses = np.asarray(odometry.stamps, float), np.asarray(odometry.poses, float)
    else:
        stamps, poses = (np.asarray(a, float) for a in odometry)
    order = np.argsort(stamps, kind='stable')
    stamps, poses = stamps[order], poses[order]
    k = 0
    out = []
    for scan in scans:
        horizon = scan.stamp + c.odom_latency + c.odom_max_gap
        while k < stamps.size and stamps[k] <= horizon:
            est.add_odometry(stamps[k], poses[k])
            k += 1
        out.append(est.update(scan))
    return out
