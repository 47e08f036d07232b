"""Ego-motion: the scanner's motion between scans from odometry plus ICP scan matching.

No ROS; each scan is one compiled kernel call (:func:`_scan_step`: the prediction, the scan
match of :mod:`laser_tracker.core.icp`, the fusion, the checks, the adaptive prior and the
pose chain; with a self-mask, its masking and learning too). Usage, one estimator per scan
stream::

    est = EgoMotionEstimator(EgoMotionConfig())
    est.add_odometry(stamp, (x, y, theta))     # every odometry sample, as it arrives
    e = est.update(scan)                       # every Scan -> EgoMotionEstimate
    e.pose      # (3,) scanner pose in the odometry frame (NaN only when source == 'none')
    e.motion    # (3,) motion since the previous scan (previous scanner frame)
    e.covariance, e.source, e.reason, e.coasting, e.ok

Offline, with the whole odometry as a PoseTrack: :func:`estimate_track`.

Roles: :class:`OdometryBuffer` (the odometry stream), :class:`MotionPrior` (the prediction
and its adaptive noise: :func:`_prediction`, :func:`_learn_prior`), :class:`ScanMatcher`
(the scan's points, the local map and ICP: :func:`_match_and_fuse`), the fusion (ICP and the
prediction by information: :func:`_fuse`, :func:`_fused`) and the checks of the fused motion
(:func:`_implausible`); :class:`EgoMotionEstimator` holds the pose chain and runs them per
scan, in one kernel call; Python makes the estimate and its texts of what the kernel
found.

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
   Without odometry, a match from the constant-velocity guess that is refused is tried
   once more from standstill with ``standstill_retry`` (the platform stopped, or its last
   motion came from a wrong match). A refused match never restarts the pose chain: the
   platform coasts on its prediction (source ``odometry`` or ``constant_velocity``,
   ``coasting`` True; detection gates such a scan, see ``difference.pose_quality``). After
   ``max_lost_scans`` scans in a row without a match (or at once when the map is too small
   to match against, or when the scan comes more than ``max_gap`` after the previous one
   with no odometry across the gap) the local map is re-seeded from the current scan at its
   coasted pose; the pose chain goes on.

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
from laser_tracker.core.geometry import plain_floats, wrap_scalar
from laser_tracker.core.scan import Scan, beam_table
from laser_tracker.core.self_mask import learn_scan, mask_scan

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
_TWO_PI = 2.0 * _PI


@dataclass(frozen=True)
class EgoMotionConfig:
    """Section ``ego_motion``: odometry prior, ICP and the acceptance checks."""

    # --- scanner mounting (base_link -> laser)
    mount_x: float = param(0.0, 'Scanner position on the platform, forward (m).',
                           min=-10.0, max=10.0)
    mount_y: float = param(0.0, 'Scanner position on the platform, left (m).',
                           min=-10.0, max=10.0)
    mount_yaw: float = param(0.0, 'Scanner yaw on the platform (rad).', min=-_PI, max=_PI)
    mount_upside_down: bool = param(
        False, 'The scanner hangs upside down (rolled or pitched by 180 deg): its scans are '
        'turned over into those of the same scanner right side up (its left is the '
        'platform\'s right) before ego-motion and detection use them; mount_yaw is then where '
        'its x axis points. For a driver without such an option (the SICK driver has '
        '"inverted": set one of the two, not both). A replay sets it from the recording\'s '
        'transforms.')
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
    max_gap: float = param(
        0.0, 'A scan more than this (s) after the previous one, with no odometry across the '
        'gap, whose match is refused re-seeds the local map at once (where the platform went '
        'meanwhile is unknown, so later matches against the old map fail too), instead of '
        'after max_lost_scans. The pose chain continues. 0 = off (the default and the paper: '
        'the scans coasted until then are no detection\'s, see README.md, "Ego-motion").',
        min=0.0, max=3600.0)
    standstill_retry: bool = param(
        False, 'Without odometry, when the match from the constant-velocity guess is refused, '
        'match again from the platform standing still and take that match if it passes: a '
        'platform that stopped, or whose last motion came from a wrong match, is found again '
        'instead of coasting on a motion it no longer has (every later match starting from '
        'it). See README.md, "Real recordings", played backwards.')
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
    #: (3, 3) of ``pose`` in the odometry frame: the motions' covariances accumulated since
    #: the pose chain (re)started (None: no pose)
    pose_covariance: np.ndarray | None = None

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
        return self.add_finite(t, x, y, th)

    def add_finite(self, t: float, x: float, y: float, th: float) -> tuple[str, str] | None:
        """:meth:`add` of a sample already known to be four finite floats."""
        p = (x, y, (th + _PI) % _TWO_PI - _PI)      # geometry.wrap_scalar
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
        """Forget samples older than ``before`` (keeping one for interpolation), once more
        than 64 are."""
        ts = self._t
        if len(ts) > 65 and ts[65] < before:
            i = bisect.bisect_left(ts, before) - 1
            del ts[:i], self._p[:i], self._seg[:i]

    def at_scan(self, t: float) -> tuple[tuple[float, float, float] | None, int, str]:
        """:meth:`pose_at` for a scan stamped ``t``: read at ``t + odom_latency`` (the
        platform's pose; the estimator applies the scanner's mounting); samples older than
        ``odom_buffer`` are forgotten."""
        c = self.config
        odo, seg, reason = self.pose_at(t + c.odom_latency)
        if odo is not None:
            self.trim(t + c.odom_latency - c.odom_buffer)
        return odo, seg, reason

    def pose_at(self, t: float) -> tuple[tuple[float, float, float] | None, int, str]:
        """``((x, y, theta), segment, '')`` at time ``t``, or ``(None, -1, reason)``."""
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
                return (p1[0] + (p1[0] - p0[0]) * f, p1[1] + (p1[1] - p0[1]) * f,
                        wrap_scalar(p1[2] + wrap_scalar(p1[2] - p0[2]) * f)), self._seg[-1], ''
            return p1, self._seg[-1], ''
        if t < ts[0]:
            return None, -1, f'no odometry before the scan (first sample {ts[0] - t:.3f} s later)'
        i = bisect.bisect_left(ts, t)
        if ts[i] == t:
            return self._p[i], self._seg[i], ''
        t0, t1 = ts[i - 1], ts[i]
        if self._seg[i - 1] != self._seg[i]:
            return None, -1, 'odometry jumped at the scan time'
        if t1 - t0 > c.odom_max_gap:
            return None, -1, f'odometry gap of {t1 - t0:.3f} s around the scan'
        p0, p1 = self._p[i - 1], self._p[i]
        f = (t - t0) / (t1 - t0)
        return (p0[0] + (p1[0] - p0[0]) * f, p0[1] + (p1[1] - p0[1]) * f,
                wrap_scalar(p0[2] + wrap_scalar(p1[2] - p0[2]) * f)), self._seg[i], ''


# ------------------------------------------------------------------- adaptive prior

#: Layout of one adapted noise model's state (a row of :attr:`MotionPrior.noise`): the Gram
#: matrix of f, the right-hand sides (x, theta), the sum of f^2, the count, the fixed model
#: c0 and the coefficients (x row, theta row).
_GRAM, _RHS, _F2, _COUNT, _C0, _COEF, _NOISE = 0, 9, 15, 18, 19, 25, 31
#: The rows of :attr:`MotionPrior.noise`: odometry, the constant-velocity motion model.
_ODOMETRY_MODEL, _MOTION_MODEL = 0, 1


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
    clipped sample still raises the estimate). The state is one row of floats (``state``,
    layout ``_GRAM`` ... ``_COEF``) that the estimator's kernel updates in place
    (:func:`_update_noise`).
    """

    def __init__(self, cx0, ct0, memory: int, weight: float, clip: float,
                 state: np.ndarray | None = None):
        self.c0 = (tuple(float(v) for v in cx0), tuple(float(v) for v in ct0))
        self.forget = 1.0 - 1.0 / max(float(memory), 1.0)
        self.weight = float(weight)
        self.clip2 = float(clip) ** 2
        self.state = np.zeros(_NOISE) if state is None else state
        self.state[:] = 0.0
        self.state[_C0:_COEF] = np.array(self.c0).ravel()
        self.state[_COEF:_NOISE] = self.state[_C0:_COEF]
        self.settings = np.array([self.forget, self.weight, self.clip2])
        jit.compiled('ego-motion kernels (adaptive prior)', _exercise_noise)

    @property
    def coef(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """The coefficients: ``(cx, ct)``."""
        cx, ct = self.state[_COEF:_NOISE].reshape(2, 3).tolist()
        return tuple(cx), tuple(ct)

    @property
    def count(self) -> float:
        """Effective number of matches learnt from (forgetting included)."""
        return float(self.state[_COUNT])

    def variance(self, motion) -> tuple[float, float]:
        """``(var_xy, var_theta)`` of a prediction ``motion`` (x, y, theta)."""
        m = plain_floats(motion)
        return _noise_variance(self.state, float(m[0]), float(m[1]), float(m[2]))

    def update(self, motion, error, icp_variance) -> None:
        """One disagreement ``error`` (x, y, theta) of the prediction ``motion`` with an ICP
        motion of variance ``icp_variance`` (x, y, theta)."""
        m, e = plain_floats(motion), plain_floats(error)
        _update_noise(float(m[0]), float(m[1]), float(m[2]), float(e[0]), float(e[1]),
                      float(e[2]), float(icp_variance[0]), float(icp_variance[1]),
                      float(icp_variance[2]), self.settings, self.state)


@jit.kernel
def _noise_variance(state, m0, m1, m2):
    """``(var_xy, var_theta)`` of a prediction ``m`` by the coefficients of ``state``."""
    d2 = m0 * m0 + m1 * m1
    a2 = m2 * m2
    c = _COEF
    return (_at_least(state[c] + state[c + 1] * d2 + state[c + 2] * a2, 1e-10),
            _at_least(state[c + 3] + state[c + 4] * d2 + state[c + 5] * a2, 1e-12))


@jit.kernel
def _update_noise(m0, m1, m2, e0, e1, e2, iv0, iv1, iv2, settings, state):
    """:meth:`AdaptiveNoise.update` in place on its ``state``: the sample of the prediction
    ``m`` (disagreement ``e``, ICP variance ``iv``) added with forgetting, and the
    coefficients solved again."""
    forget, weight, clip2 = settings[0], settings[1], settings[2]
    vxy, vth = _noise_variance(state, m0, m1, m2)
    d2 = m0 * m0 + m1 * m1
    a2 = m2 * m2
    ix = 0.5 * (iv0 + iv1)
    ex2 = _at_most(0.5 * (e0 * e0 + e1 * e1), clip2 * (vxy + ix)) - ix
    et2 = _at_most(e2 * e2, clip2 * (vth + iv2)) - iv2
    g = forget
    f = (1.0, d2, a2)
    for i in range(3):             # (f[0] = 1: its products are exactly the other factor)
        for j in range(i, 3):
            gram = g * state[_GRAM + 3 * i + j] + f[i] * f[j]
            state[_GRAM + 3 * i + j] = state[_GRAM + 3 * j + i] = gram
        state[_RHS + i] = g * state[_RHS + i] + f[i] * ex2
        state[_RHS + 3 + i] = g * state[_RHS + 3 + i] + f[i] * et2
        state[_F2 + i] = g * state[_F2 + i] + f[i] * f[i]
    count = g * state[_COUNT] + 1.0
    state[_COUNT] = count
    # the ridge weights: the fixed model counts as ``weight`` samples of each f^2
    n = _at_least(count, 1e-12)
    pen = np.empty(3)
    for i in range(3):
        pen[i] = weight * state[_F2 + i] / n
    top = _at_least(_at_least(pen[0], pen[1]), pen[2]) + 1e-300
    for i in range(3):
        pen[i] = pen[i] + 1e-9 * top
    gram = state[_GRAM:_RHS].copy().reshape(3, 3)
    for k in range(2):
        _nonnegative_ridge(gram, state[_RHS + 3 * k:_RHS + 3 * k + 3], pen,
                           state[_C0 + 3 * k:_C0 + 3 * k + 3],
                           state[_COEF + 3 * k:_COEF + 3 * k + 3])


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


def _exercise_noise() -> None:
    """:func:`_update_noise` and :func:`_noise_variance` compiled (or loaded)."""
    state = np.zeros(_NOISE)
    state[_C0:_NOISE] = 1e-4
    _update_noise(0.1, 0.0, 0.01, 0.01, 0.0, 0.001, 1e-5, 1e-5, 1e-7,
                  np.array([0.98, 5.0, 9.0]), state)
    _noise_variance(state, 0.1, 0.0, 0.01)


# ------------------------------------------------------------------------ prediction


class MotionPrior:
    """Step 1 and 2 of the method: the prediction and its noise, fixed (``odom_sigma_*``,
    ``cv_sigma_*``) or adapted to the accepted matches (``adaptive_prior``). Its state is
    :attr:`noise` (one row per model, :class:`AdaptiveNoise`'s layout), read and updated by
    the estimator's kernel (:func:`_prediction`, :func:`_learn_prior`)."""

    def __init__(self, config: EgoMotionConfig):
        c = self.config = config
        self.noise = np.zeros((2, _NOISE))
        self.odometry_noise = AdaptiveNoise(
            (c.odom_sigma_xy ** 2, c.odom_sigma_xy_per_m ** 2, 0.0),
            (c.odom_sigma_theta ** 2, c.odom_sigma_theta_per_m ** 2,
             c.odom_sigma_theta_per_rad ** 2),
            c.adaptive_memory, c.adaptive_weight, c.adaptive_clip,
            self.noise[_ODOMETRY_MODEL])
        self.motion_model_noise = AdaptiveNoise(
            (c.cv_sigma_xy ** 2, 0.0, 0.0), (c.cv_sigma_theta ** 2, 0.0, 0.0),
            c.adaptive_memory, c.adaptive_weight, c.adaptive_clip,
            self.noise[_MOTION_MODEL])

    def settings(self) -> list[float]:
        """The prior's part of the estimator's settings (``_S_ADAPTIVE`` ... ``_S_NOISE``):
        adaptive or not, the information of a guess without any motion seen (standing: weak),
        the fixed models (sigma per step, per metre, per radian; x then theta, odometry then
        motion model), and the adapted models' forgetting, weight and clip."""
        c = self.config
        return [float(c.adaptive_prior),
                0.01 / c.cv_sigma_xy ** 2, 0.01 / c.cv_sigma_xy ** 2,
                0.01 / c.cv_sigma_theta ** 2,
                c.odom_sigma_xy, c.odom_sigma_xy_per_m, 0.0,
                c.odom_sigma_theta, c.odom_sigma_theta_per_m, c.odom_sigma_theta_per_rad,
                c.cv_sigma_xy, 0.0, 0.0, c.cv_sigma_theta, 0.0, 0.0,
                *self.odometry_noise.settings.tolist()]


# ----------------------------------------------------------------------------- match


class ScanMatcher:
    """Step 3: the scan's points matched against the local map of the last key scans
    (:mod:`laser_tracker.core.icp`): its schedule, the map, and the checks and fusion
    settings the estimator's kernel reads."""

    def __init__(self, config: EgoMotionConfig):
        c = self.config = config
        hi, lo, n = c.association_distance, c.association_distance_final, c.association_levels
        distances = (lo,) if n == 1 or hi <= lo else \
            tuple(float(v) for v in np.geomspace(hi, lo, n))
        self.schedule = icp.Schedule.of(
            distances, c.kernel_ratio, c.steps_per_association, c.final_associations,
            converged_translation=c.converged_translation,
            converged_rotation=c.converged_rotation, coarse_stride=c.coarse_stride)
        self.map = icp.LocalMap(c.map_scans, c.normal_max_gap,
                                capacity=min(c.map_scans * c.max_points, 4096))
        #: the checks and the fusion's settings, as :func:`_match_and_fuse` reads them
        self.checks = [c.min_points, c.min_inlier_ratio, c.max_rms, c.degeneracy_threshold,
                       c.icp_model_sigma ** 2, c.prior_max_ratio, c.prior_gate,
                       c.prior_gate ** 2, 2.0]
        icp.warm_up()

    def clear(self) -> None:
        self.map.clear()

    def match(self, scan: Scan, pose0=None) -> tuple[np.ndarray, icp.IcpResult | None]:
        """The scan's valid points (``Scan.valid()`` within ``min_range``/``max_range``, at
        most ``max_points``) and their ICP result from ``pose0`` (None: not matched, or too
        few points or map points)."""
        c = self.config
        _, cos, sin = beam_table(float(scan.angle_min), float(scan.angle_increment),
                                 scan.n_beams)
        return icp.match_scan(scan.ranges, cos, sin, max(scan.range_min, 1e-6),
                              scan.range_max, c.min_range, c.max_range, c.max_points,
                              c.min_points, self.map, pose0, self.schedule)


# ---------------------------------------------------------------------------- the kernel
#
# One kernel call per scan (:func:`_scan_step`) does the method's steps 1-5, the pose
# chain's bookkeeping (key scans, re-seeding), the pose's covariance and, with a self-mask,
# the masking before the match and the learning after it. It computes as the numpy and
# Python formulation it replaced, operation for operation (results equal bit for bit):
# Python's ``math.hypot`` is CPython's (``jit.python_hypot``), ``x ** 2`` libm's pow (a
# run-time exponent, ``_S_TWO``, keeps the compiler from folding it into ``x * x``),
# numpy's 3x3 products sequences of fused multiply-adds as its BLAS computes them, its 3x3
# solve and inverse LAPACK's dgesv (numba's ``np.linalg.solve``). What it found is packed in
# one float array (``_O_*``), from which Python makes the estimate and its texts.


def _layout(*fields: tuple[str, int]) -> dict[str, int]:
    """Offsets of consecutive fields ``(name, width)`` of a packed float array, and its
    size (``'size'``)."""
    out, k = {}, 0
    for name, width in fields:
        out[name] = k
        k += width
    out['size'] = k
    return out


#: The pose chain (:attr:`EgoMotionEstimator.chain`): a pose?, the pose, its stamp, a motion
#: seen?, the previous motion and its time step, odometry at the previous scan? and its
#: scanner pose and segment, scans without a match, a key scan? and its pose, the pose's
#: covariance.
_C = _layout(('has_pose', 1), ('pose', 3), ('stamp', 1), ('has_motion', 1), ('motion', 3),
             ('dt', 1), ('has_odometry', 1), ('odometry', 3), ('segment', 1), ('lost', 1),
             ('has_key', 1), ('key', 3), ('pose_covariance', 9))
_HAS_POSE, _POSE, _STAMP, _HAS_MOTION, _MOTION, _DT, _HAS_ODO, _ODO, _SEGMENT, _LOST, \
    _HAS_KEY, _KEY, _POSE_COV, _CHAIN = _C.values()

#: The estimator's settings (:func:`_settings`): the scan's points, the platform's limits,
#: the map's key scans, the mount, the prior's (:meth:`MotionPrior.settings`) and the
#: match's checks (:attr:`ScanMatcher.checks`), and 2.0 (the pow exponent).
_S = _layout(('min_points', 1), ('max_points', 1), ('min_range', 1), ('max_range', 1),
             ('speed', 1), ('turn', 1), ('jitter', 1), ('correction_t', 1),
             ('correction_r', 1), ('max_lost', 1), ('max_gap', 1), ('standstill', 1),
             ('key_t', 1), ('key_r', 1),
             ('normal_gap', 1), ('mounted', 1), ('mount', 3), ('two', 1), ('adaptive', 1),
             ('unknown', 3), ('fixed', 12), ('noise', 3), ('checks', 9))
_S_MIN_POINTS, _S_MAX_POINTS, _S_MIN_RANGE, _S_MAX_RANGE, _S_SPEED, _S_TURN, _S_JITTER, \
    _S_CORRECTION_T, _S_CORRECTION_R, _S_MAX_LOST, _S_MAX_GAP, _S_STANDSTILL, _S_KEY_T, \
    _S_KEY_R, _S_NORMAL_GAP, \
    _S_MOUNTED, _S_MOUNT, _S_TWO, _S_ADAPTIVE, _S_UNKNOWN, _S_FIXED, _S_NOISE, _S_CHECKS, \
    _SETTINGS = _S.values()

#: What one scan gave (:func:`_scan_step`'s ``out``): the source (an index of ``SOURCES``),
#: pose, motion, its covariance, the pose's covariance, the time step, the odometry
#: increment (1 and the motion, or 0), scan points, matched?, inlier ratio, rms, iterations,
#: weakest eigenvalue, degenerate directions, why no increment (``_INC_*``) and its kind and
#: value, why the match was not used (``_WHY_*``) and two values, map points, the map
#: re-seeded?, scans without a match, any beam masked?
_O = _layout(('source', 1), ('pose', 3), ('motion', 3), ('covariance', 9),
             ('pose_covariance', 9), ('dt', 1), ('odometry', 4), ('n_points', 1),
             ('matched', 1), ('inlier_ratio', 1), ('rms', 1), ('iterations', 1),
             ('min_eigenvalue', 1), ('n_deg', 1), ('inc', 3), ('why', 3), ('map_points', 1),
             ('reseed', 1), ('lost', 1), ('masked', 1))
_O_SOURCE, _O_POSE, _O_MOTION, _O_COV, _O_POSE_COV, _O_DT, _O_ODOMETRY, _O_N_POINTS, \
    _O_MATCHED, _O_INLIER_RATIO, _O_RMS, _O_ITERATIONS, _O_MIN_EIG, _O_N_DEG, _O_INC, \
    _O_WHY, _O_MAP_POINTS, _O_RESEED, _O_LOST, _O_MASKED, _OUT = _O.values()

#: Sources by index (``out[_O_SOURCE]``).
_INIT, _ICP, _PARTIAL, _ODOMETRY, _CONSTANT_VELOCITY = range(5)
#: Why there is no odometry increment: none missing, no odometry at the scan (the buffer
#: says why), none at the previous scan, a jump between them, a step faster than the
#: platform (kind 1: translation, 2: rotation; and the speed).
_INC_OK, _INC_MISSING, _INC_NO_PREVIOUS, _INC_JUMPED, _INC_TOO_FAST = range(5)
#: Why a match is not used: it is, too few scan points, too small a map (its points), the
#: match's verdicts (``FEW_INLIERS`` ... ``DEGENERATE``, 2-7; and its inliers), faster than
#: the platform (kind, speed), disagreeing with odometry (distance, angle).
_WHY_NONE, _WHY_FEW_POINTS, _WHY_SMALL_MAP, _WHY_TOO_FAST, _WHY_DISAGREES = 0, 8, 9, 10, 11


@jit.kernel
def _scan_step(t, ranges, cos, sin, valid_min, valid_max, increment, odo_has, ox, oy, oth,
               oseg, chain, settings, noise, schedule, icp_settings, rows, grid_xy, order,
               start, grid, map_state, mask_settings, mask_state, masked_ranges, out):
    """One scan (stamped ``t``, beams ``ranges``; its odometry: ``odo_has``, the platform's
    pose ``ox, oy, oth`` and segment ``oseg``) in place on the pose chain (``chain``), the
    adapted noise (``noise``), the local map's buffers and, with a self-mask
    (``mask_settings`` not empty), its state; what it gave into ``out`` (``_O_*``) and the
    masked ranges into ``masked_ranges``."""
    out[:] = 0.0
    out[_O_RMS] = out[_O_MIN_EIG] = np.nan
    masking = mask_settings.size > 0
    skip = np.zeros(ranges.size if masking else 0, np.bool_)
    if masking:
        out[_O_MASKED] = mask_scan(ranges, valid_min, valid_max, increment, mask_settings,
                                   mask_state, masked_ranges, skip)
    odo = np.array([ox, oy, oth])
    if odo_has and settings[_S_MOUNTED]:
        odo = _compose(odo, settings[_S_MOUNT:_S_MOUNT + 3])
    if not chain[_HAS_POSE]:
        _first_scan(t, ranges, skip, cos, sin, valid_min, valid_max, odo_has, odo, oseg,
                    chain, settings, rows, grid_xy, order, start, grid, map_state, out)
        return
    pose = chain[_POSE:_POSE + 3].copy()
    dt = t - chain[_STAMP]
    out[_O_DT] = dt
    # 1-2. the prediction: the odometry increment, else constant velocity; and its prior
    inc = _odometry_increment(odo_has, odo, oseg, dt, chain, settings, out)
    has_inc = out[_O_INC] == _INC_OK
    motion_p, info, cv = _prediction(has_inc, inc, dt, chain, settings, noise)
    predicted = _compose(pose, motion_p)
    # 3-4. the match from the predicted pose, fused with the prediction when it passes the
    # match's checks
    n_map = map_state[icp._ROWS]
    checks = settings[_S_CHECKS:_SETTINGS]
    pts, packed = _match_and_fuse(
        ranges, skip, cos, sin, valid_min, valid_max, settings[_S_MIN_RANGE],
        settings[_S_MAX_RANGE], int(settings[_S_MAX_POINTS]), int(settings[_S_MIN_POINTS]),
        predicted, schedule, icp_settings, rows[:n_map], grid_xy[:n_map], order[:n_map],
        start, grid, pose, info, checks)
    n_pts = pts.shape[0]
    verdict, n_deg = int(packed[_VERDICT]), int(packed[_N_DEG])
    matched = verdict != UNMATCHED
    out[_O_N_POINTS], out[_O_MATCHED], out[_O_MAP_POINTS] = n_pts, matched, n_map
    if matched:
        _match_figures(out, n_pts, packed)
    # 5. the fused motion's checks
    motion, fused_pose, cov = np.full(3, np.nan), np.full(3, np.nan), np.full((3, 3), np.nan)
    info_icp = np.full((3, 3), np.nan)
    if verdict == UNMATCHED:
        out[_O_WHY] = _WHY_FEW_POINTS if n_pts < settings[_S_MIN_POINTS] else \
            (_WHY_SMALL_MAP if n_map < settings[_S_MIN_POINTS] else _WHY_NONE)
        out[_O_WHY + 1] = n_map
    elif verdict != FUSED:
        out[_O_WHY], out[_O_WHY + 1] = verdict, packed[icp._N_IN]
    else:
        fused_pose, motion, info_icp, _, cov = _fused(packed, n_deg, pose, predicted, checks)
        _implausible(motion, predicted, fused_pose, has_inc, dt, settings, out)
    accepted = verdict == FUSED and out[_O_WHY] == _WHY_NONE
    if not accepted and not has_inc and settings[_S_STANDSTILL] > 0.0 and n_map > 0 \
            and (cv[0] != 0.0 or cv[1] != 0.0 or cv[2] != 0.0):
        # the constant-velocity guess failed: try the platform standing still
        info_z = _information(_MOTION_MODEL, np.zeros(3), settings, noise)
        pts_z, packed_z = _match_and_fuse(
            ranges, skip, cos, sin, valid_min, valid_max, settings[_S_MIN_RANGE],
            settings[_S_MAX_RANGE], int(settings[_S_MAX_POINTS]),
            int(settings[_S_MIN_POINTS]), pose, schedule, icp_settings, rows[:n_map],
            grid_xy[:n_map], order[:n_map], start, grid, pose, info_z, checks)
        if int(packed_z[_VERDICT]) == FUSED:
            n_deg_z = int(packed_z[_N_DEG])
            fused_z, motion_z, info_icp_z, _, cov_z = _fused(packed_z, n_deg_z, pose, pose,
                                                              checks)
            why = out[_O_WHY:_O_WHY + 3].copy()
            out[_O_WHY:_O_WHY + 3] = 0.0
            _implausible(motion_z, pose, fused_z, has_inc, dt, settings, out)
            if out[_O_WHY] == _WHY_NONE:       # the same points, matched from standstill
                accepted = True
                pts, packed, n_deg = pts_z, packed_z, n_deg_z
                fused_pose, motion, info_icp, cov = fused_z, motion_z, info_icp_z, cov_z
                out[_O_MATCHED] = 1.0
                _match_figures(out, n_pts, packed)
            else:
                out[_O_WHY:_O_WHY + 3] = why
    lost = chain[_LOST]
    reseed = False
    if accepted:
        if n_deg == 0 and settings[_S_ADAPTIVE]:
            _learn_prior(packed, info_icp, pose, has_inc, inc, cv, chain[_HAS_MOTION] != 0,
                         noise, settings)
        source = _PARTIAL if n_deg else _ICP
        out[_O_N_DEG] = n_deg
        lost = 0.0
    else:        # the platform coasts on its prediction; the pose chain goes on
        source = _ODOMETRY if has_inc else _CONSTANT_VELOCITY
        map_ok = n_map >= settings[_S_MIN_POINTS]
        if matched or not map_ok:      # a match was tried and refused, or nothing to match
            lost += 1.0
        after_gap = not has_inc and 0.0 < settings[_S_MAX_GAP] < dt
        reseed = n_pts >= settings[_S_MIN_POINTS] and (
            not map_ok or lost >= settings[_S_MAX_LOST] or after_gap)
        motion = motion_p
        cov = np.zeros((3, 3))
        for k in range(3):
            cov[k, k] = 1.0 / info[k]
    new_pose = _compose(pose, motion)
    out[_O_SOURCE], out[_O_RESEED], out[_O_LOST] = source, reseed, lost
    out[_O_POSE:_O_POSE + 3] = new_pose
    out[_O_MOTION:_O_MOTION + 3] = motion
    out[_O_COV:_O_COV + 9] = cov.ravel()
    if has_inc:
        out[_O_ODOMETRY] = 1.0
        out[_O_ODOMETRY + 1:_O_ODOMETRY + 4] = inc
    # the pose chain moves on; the scan joins the local map when it was placed by ICP or
    # odometry (a guess would pollute the map) and has moved since the last key scan, or
    # re-seeds it
    chain[_POSE:_POSE + 3] = new_pose
    chain[_STAMP] = t
    _remember_odometry(odo_has, odo, oseg, chain)
    chain[_HAS_MOTION] = 1.0
    chain[_MOTION:_MOTION + 3] = motion
    chain[_DT] = dt
    if reseed:
        lost = 0.0
        chain[_HAS_KEY] = 0.0
        map_state[icp._ROWS] = map_state[icp._SCANS] = 0
        icp._grid_hash(rows, 0, icp.CELL, grid_xy, order, start, grid)
        _add_key_scan(pts, new_pose, chain, settings, rows, grid_xy, order, start, grid,
                      map_state)
    elif source != _CONSTANT_VELOCITY and _moved_since_key_scan(new_pose, chain, settings):
        _add_key_scan(pts, new_pose, chain, settings, rows, grid_xy, order, start, grid,
                      map_state)
    chain[_LOST] = lost
    if not (math.isfinite(new_pose[0]) and math.isfinite(new_pose[1])
            and math.isfinite(new_pose[2])):
        _copy_pose_covariance(chain, out)
        return
    # the pose's covariance: the motion's, turned into the odometry frame
    if np.isfinite(cov).all():
        turn = new_pose[2] - motion[2]
        c, s = math.cos(turn), math.sin(turn)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        added = _matmul3(_matmul3(rot, cov), rot.T.copy())
        for i in range(3):
            for j in range(3):
                k = _POSE_COV + 3 * i + j
                chain[k] = chain[k] + added[i, j]
    _copy_pose_covariance(chain, out)
    # the self-mask learns from measured motion: the odometry increment when there is one
    # (the match itself may be pulled towards standing still by the body it has not learnt
    # yet), else an accepted match; a guessed motion (the constant-velocity model while a
    # standing robot's matches are refused) would make anything that stands in front of it
    # look like its body
    if masking and (has_inc or source == _ICP or source == _PARTIAL):
        learnt = inc if has_inc else motion
        learn_scan(ranges, cos, sin, valid_min, valid_max, learnt[0], learnt[1], learnt[2],
                   mask_settings, mask_state)


@jit.inline
def _first_scan(t, ranges, skip, cos, sin, valid_min, valid_max, odo_has, odo, oseg, chain,
                settings, rows, grid_xy, order, start, grid, map_state, out):
    """The first scan (or the first after a reset): the pose chain starts at the odometry
    pose (else the origin) and the scan's points seed the local map."""
    pts = icp._scan_points(ranges, skip, cos, sin, valid_min, valid_max,
                           settings[_S_MIN_RANGE], settings[_S_MAX_RANGE],
                           int(settings[_S_MAX_POINTS]))
    lost_map = map_state[icp._ROWS]
    chain[:] = 0.0
    map_state[icp._ROWS] = map_state[icp._SCANS] = 0
    if lost_map:
        icp._grid_hash(rows, 0, icp.CELL, grid_xy, order, start, grid)
    pose = odo.copy() if odo_has else np.zeros(3)
    chain[_HAS_POSE] = 1.0
    chain[_POSE:_POSE + 3] = pose
    chain[_STAMP] = t
    _remember_odometry(odo_has, odo, oseg, chain)
    _add_key_scan(pts, pose, chain, settings, rows, grid_xy, order, start, grid, map_state)
    out[_O_SOURCE] = _INIT
    out[_O_POSE:_O_POSE + 3] = pose
    out[_O_N_POINTS] = pts.shape[0]
    out[_O_ODOMETRY] = odo_has


@jit.inline
def _remember_odometry(odo_has, odo, oseg, chain):
    """The scan's odometry (scanner pose and segment) for the next scan's increment."""
    chain[_HAS_ODO] = odo_has
    if odo_has:
        chain[_ODO:_ODO + 3] = odo
        chain[_SEGMENT] = oseg
    else:
        chain[_SEGMENT] = -1.0


@jit.inline
def _copy_pose_covariance(chain, out):
    out[_O_POSE_COV:_O_POSE_COV + 9] = chain[_POSE_COV:_POSE_COV + 9]


@jit.inline
def _add_key_scan(pts, pose, chain, settings, rows, grid_xy, order, start, grid, map_state):
    """The scan at ``pose`` joins the local map (a scan of fewer than 2 points does not)."""
    if pts.shape[0] < 2:
        return
    icp._add_scan(pts, pose, settings[_S_NORMAL_GAP], 0.05, icp.CELL, rows, grid_xy, order,
                  start, grid, map_state)
    chain[_HAS_KEY] = 1.0
    chain[_KEY:_KEY + 3] = pose


@jit.inline
def _moved_since_key_scan(pose, chain, settings):
    """The scanner moved ``map_min_translation`` or turned ``map_min_rotation`` since the
    last key scan (or there is none)."""
    if not chain[_HAS_KEY]:
        return True
    d = _between(chain[_KEY:_KEY + 3], pose)
    return jit.python_hypot(d[0], d[1]) >= settings[_S_KEY_T] or abs(d[2]) >= settings[_S_KEY_R]


@jit.inline
def _too_fast(x, y, theta, dt, settings):
    """``(kind, speed)``: a motion ``x, y, theta`` over ``dt`` seconds beyond the platform's
    limits (kind 1: translation, m/s; 2: rotation, rad/s), or ``(0, 0.0)``; scan stamps
    jitter, so the step may take ``speed_check_jitter`` longer."""
    if dt <= 0.0:
        return 0, 0.0
    span = dt + settings[_S_JITTER]
    v = jit.python_hypot(x, y) / span
    w = abs(theta) / span
    if v > settings[_S_SPEED]:
        return 1, v
    if w > settings[_S_TURN]:
        return 2, w
    return 0, 0.0


@jit.inline
def _odometry_increment(odo_has, odo, oseg, dt, chain, settings, out):
    """The odometry motion since the previous scan (``out[_O_INC]`` says why there is none:
    ``_INC_*``, then the kind and the speed of a step too fast)."""
    inc = np.zeros(3)
    if not odo_has:
        out[_O_INC] = _INC_MISSING
    elif not chain[_HAS_ODO]:
        out[_O_INC] = _INC_NO_PREVIOUS
    elif oseg != chain[_SEGMENT]:
        out[_O_INC] = _INC_JUMPED
    else:
        inc = _between(chain[_ODO:_ODO + 3], odo)
        kind, speed = _too_fast(inc[0], inc[1], inc[2], dt, settings)
        if kind:
            out[_O_INC], out[_O_INC + 1], out[_O_INC + 2] = _INC_TOO_FAST, kind, speed
    return inc


@jit.inline
def _match_figures(out, n_pts, packed):
    """The match's inlier ratio, residual, iterations and weakest eigenvalue into ``out``."""
    out[_O_INLIER_RATIO] = packed[icp._N_IN] / n_pts if n_pts else 0.0
    out[_O_RMS] = packed[icp._RMS]
    out[_O_ITERATIONS] = packed[icp._ITERATIONS]
    out[_O_MIN_EIG] = packed[icp.EIGENVALUES]


@jit.inline
def _prediction(has_inc, inc, dt, chain, settings, noise):
    """``(motion, information, constant velocity)``: the odometry increment when usable,
    else the previous motion (over its time step) scaled to ``dt`` (constant velocity, at
    most 3 times), and the prior's information (diagonal x, y, theta)."""
    cv = np.zeros(3)
    has_motion = chain[_HAS_MOTION] != 0.0
    if has_motion and not chain[_DT] <= 0.0:
        f = _at_most(dt / chain[_DT], 3.0)
        for k in range(3):
            cv[k] = chain[_MOTION + k] * f
    if has_inc:
        return inc, _information(_ODOMETRY_MODEL, inc, settings, noise), cv
    if not has_motion:
        return cv, settings[_S_UNKNOWN:_S_UNKNOWN + 3].copy(), cv
    return cv, _information(_MOTION_MODEL, cv, settings, noise), cv


@jit.inline
def _information(model, m, settings, noise):
    """The information (diagonal x, y, theta) of a prediction ``m`` of ``model``: the
    adapted noise, or the fixed model (sigma = per step + per metre * d + per radian * |a|)."""
    if settings[_S_ADAPTIVE]:
        vxy, vth = _noise_variance(noise[model], m[0], m[1], m[2])
        return np.array([1.0 / vxy, 1.0 / vxy, 1.0 / vth])
    fixed = settings[_S_FIXED + 6 * model:_S_FIXED + 6 * model + 6]
    d = jit.python_hypot(m[0], m[1])
    sxy = fixed[0] + fixed[1] * d
    sth = fixed[3] + fixed[4] * d + fixed[5] * abs(m[2])
    ixy = 1.0 / math.pow(sxy, settings[_S_TWO])
    return np.array([ixy, ixy, 1.0 / math.pow(sth, settings[_S_TWO])])


@jit.inline
def _fused(packed, n_deg, previous, predicted, checks):
    """Step 4's result (``_match_and_fuse`` fused along the constrained directions):
    ``(pose, motion, ICP's information, prior used, covariance)``; along degenerate
    directions (scaled coordinates z = delta / sv) the prediction is kept and ICP gives no
    information."""
    pose = packed[_F_POSE:_F_POSE + 3].copy()
    info = packed[_F_INFO:_F_INFO + 9].copy().reshape(3, 3)
    lam = packed[_F_PRIOR:_F_PRIOR + 3].copy()
    if not n_deg:
        return (pose, packed[_F_MOTION:_F_MOTION + 3].copy(), info, lam,
                packed[_F_COV:_F_COV + 9].copy().reshape(3, 3))
    evals = packed[icp.EIGENVALUES:icp.EIGENVALUES + 3]
    evecs = packed[icp.EIGENVECTORS:icp.EIGENVECTORS + 9].copy().reshape(3, 3)
    sv = np.array([1.0, 1.0, 1.0 / packed[icp._SCALE]])
    z = _between(predicted, pose) / sv
    keep = np.empty(3, np.int64)
    deg = np.empty(3, np.int64)
    n_keep = 0
    for j in range(3):
        if evals[j] < checks[3]:
            deg[j - n_keep] = j
        else:
            keep[n_keep] = j
            n_keep += 1
    # u^T z and u (u^T z), u the constrained eigenvectors, as numpy's BLAS computes them
    w = np.empty(n_keep)
    for a in range(n_keep):
        u = evecs[:, keep[a]]
        if n_keep == 1:
            w[a] = (u[0] * z[0] + u[1] * z[1]) + u[2] * z[2]
        else:
            w[a] = jit.fma(u[2], z[2], jit.fma(u[0], z[0], u[1] * z[1]))
    step = np.empty(3)
    for i in range(3):
        acc = evecs[i, keep[0]] * w[0]
        for a in range(1, n_keep):
            acc = acc + evecs[i, keep[a]] * w[a]
        step[i] = sv[i] * acc
    pose = _compose(predicted, step)
    # no ICP information along them: S^-1 P S H S P S^-1, P = I - v v^T
    proj = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for a in range(3 - n_keep):
                acc = jit.fma(evecs[i, deg[a]], evecs[j, deg[a]], acc)
            proj[i, j] = (1.0 if i == j else 0.0) - acc
    s, s_inv = np.zeros((3, 3)), np.zeros((3, 3))
    for k in range(3):
        s[k, k], s_inv[k, k] = sv[k], 1.0 / sv[k]
    info = _matmul3(_matmul3(_matmul3(_matmul3(_matmul3(_matmul3(s_inv, proj), s), info), s),
                             proj), s_inv)
    return pose, _between(previous, pose), info, lam, _covariance(info, lam)


@jit.inline
def _matmul3(a, b):
    """``a @ b`` of 3x3 matrices as numpy's BLAS computes it: each entry a sequence of fused
    multiply-adds from zero."""
    out = np.empty((3, 3))
    for p in range(3):
        for q in range(3):
            acc = 0.0
            for k in range(3):
                acc = jit.fma(a[p, k], b[k, q], acc)
            out[p, q] = acc
    return out


@jit.inline
def _implausible(motion, predicted, pose, has_inc, dt, settings, out):
    """Step 5, the fused match's checks: the platform's speed limits and, with odometry, the
    correction of the ``predicted`` pose (``out[_O_WHY]``: ``_WHY_TOO_FAST``, kind and
    speed; ``_WHY_DISAGREES``, distance and angle)."""
    kind, speed = _too_fast(motion[0], motion[1], motion[2], dt, settings)
    if kind:
        out[_O_WHY], out[_O_WHY + 1], out[_O_WHY + 2] = _WHY_TOO_FAST, kind, speed
        return
    if has_inc:
        d = _between(predicted, pose)
        dist = jit.python_hypot(d[0], d[1])
        if dist > settings[_S_CORRECTION_T] or abs(d[2]) > settings[_S_CORRECTION_R]:
            out[_O_WHY], out[_O_WHY + 1], out[_O_WHY + 2] = _WHY_DISAGREES, dist, abs(d[2])


@jit.inline
def _learn_prior(packed, information, previous, has_inc, inc, cv, has_history, noise,
                 settings):
    """The prediction's disagreement with an accepted, fully constrained ICP motion (before
    fusion) feeds its adapted noise (the motion model's only once a motion was seen)."""
    icp_motion = _between(previous, packed[icp.POSE:icp.POSE + 3])
    a, b, c = information[0, 0], information[0, 1], information[0, 2]
    d, e, f = information[1, 1], information[1, 2], information[2, 2]
    ca, cd, cf = d * f - e * e, a * f - c * c, a * d - b * b
    det = a * ca + b * (c * e - b * f) + c * (b * e - c * d)
    if not det > 0.0:
        return
    noise_settings = settings[_S_NOISE:_S_NOISE + 3]
    if has_inc:
        err = _between(inc, icp_motion)
        _update_noise(inc[0], inc[1], inc[2], err[0], err[1], err[2], ca / det, cd / det,
                      cf / det, noise_settings, noise[_ODOMETRY_MODEL])
    elif has_history:
        err = _between(cv, icp_motion)
        _update_noise(cv[0], cv[1], cv[2], err[0], err[1], err[2], ca / det, cd / det,
                      cf / det, noise_settings, noise[_MOTION_MODEL])


@jit.kernel
def _fuse(icp_pose, hessian, sum_weights, n_deg, previous, predicted, prior, settings):
    """The fusion's algebra: ``(pose, motion, information, prior used, covariance)``.
    ICP's information ``H / (sum w * model_sigma^2)``; with no degenerate direction the
    prior's information bounded by ``prior_max_ratio`` times ICP's and gated
    (``prior_gate``); the fused pose one information-weighted step from the ICP pose
    towards the prediction. With degenerate directions (``n_deg`` > 0) the motion and the
    covariance are left to the caller (NaN), which projects them out first (:func:`_fused`)."""
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
                    grid_xy, order, start, grid, previous, prior, checks):
    """Steps 3-4 for one scan: its points, their ICP match from the ``predicted`` pose, the
    checks of the match (:func:`_verdict`) and, when it passes them, its fusion with the
    prediction (information ``prior``; :func:`_fuse`). Returns the points and the packed
    result (``icp.result``'s layout, then ``_VERDICT`` ... ``_F_COV``; NaN where not
    computed)."""
    out = np.full(_PACKED, np.nan)
    pts, matched = icp._points_and_align(
        ranges, skip, cos, sin, valid_min, valid_max, min_range, max_range, max_points,
        min_points, predicted, schedule.shape[0], schedule, icp_settings, rows, grid_xy,
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


def _settings(config: EgoMotionConfig, prior: MotionPrior, matcher: ScanMatcher) -> np.ndarray:
    """The estimator's settings (``_S_*``)."""
    c = config
    mount = (c.mount_x, c.mount_y, c.mount_yaw)
    out = np.array([c.min_points, c.max_points, c.min_range, c.max_range,
                    c.max_translation_speed, c.max_rotation_speed, c.speed_check_jitter,
                    c.max_correction_translation, c.max_correction_rotation,
                    c.max_lost_scans, c.max_gap, float(c.standstill_retry),
                    c.map_min_translation, c.map_min_rotation,
                    c.normal_max_gap, float(any(mount)), *mount, 2.0, *prior.settings(),
                    *matcher.checks], dtype=float)
    assert out.size == _SETTINGS
    return out


def _exercise_kernels() -> None:
    """:func:`_scan_step` compiled (or loaded) for the argument types of real scans (two
    scans of a small room with odometry, with and without a self-mask; every path of the
    kernel is compiled with it)."""
    from laser_tracker.core.self_mask import SelfMask, SelfMaskConfig

    angles = np.linspace(-1.5, 1.5, 61)
    ranges = 2.0 / np.maximum(np.abs(np.cos(angles)), 0.3)
    ranges[0] = np.nan
    for mask in (None, SelfMask(SelfMaskConfig())):
        est = EgoMotionEstimator(EgoMotionConfig(min_points=3), self_mask=mask)
        est.rehearses = False
        for k in range(2):
            est.add_odometry(0.1 * k, (0.0, 0.0, 0.0))
            est.update(Scan(stamp=0.1 * k, ranges=ranges, angle_min=-1.5,
                            angle_increment=0.05, range_min=0.05, range_max=8.0))


# -------------------------------------------------------------------------- estimator


class EgoMotionEstimator:
    """Odometry prior plus point-to-line ICP against a short local map (module docstring).

    Its roles: the odometry buffer (``odometry``), the prediction and its adaptive prior
    (``prior``), the match (``matcher``) and, when given, the robot's own body
    (``self_mask``: masked before the match, learnt after it); the estimator holds the pose
    chain (``chain``) and runs them per scan in one kernel call (:func:`_scan_step`).
    """

    def __init__(self, config: EgoMotionConfig | None = None, self_mask=None):
        self.config = config or EgoMotionConfig()
        self.odometry = OdometryBuffer(self.config)
        self.prior = MotionPrior(self.config)
        self.matcher = ScanMatcher(self.config)
        self.self_mask = self_mask
        self.settings = _settings(self.config, self.prior, self.matcher)
        self.chain = np.zeros(_CHAIN)
        self.stats: Counter = Counter()
        self._notes: Counter = Counter()
        #: whether this estimator's first scan may rehearse the process's first match
        #: (:func:`_rehearse`; not the warm-ups' estimators, whose scans are synthetic)
        self.rehearses = True
        self._reset_state()
        jit.compiled('ego-motion kernel', _exercise_kernels)

    # ----------------------------------------------------------------- public API

    def add_odometry(self, stamp: float, pose) -> None:
        """Feed one odometry sample (platform pose ``x, y, theta`` in the odometry frame)."""
        note = self.odometry.add(stamp, pose)
        if note:
            self._note(*note)

    def add_finite_odometry(self, t: float, x: float, y: float, theta: float) -> None:
        """:meth:`add_odometry` of a sample known to be four finite floats."""
        note = self.odometry.add_finite(t, x, y, theta)
        if note:
            self._note(*note)

    def reset(self, reason: str = 'reset requested') -> None:
        """Forget the local map and the pose chain (odometry history and the adapted noise
        are kept)."""
        self._note('reset', f'ego-motion reset: {reason}', level=logging.WARNING)
        self.stats['resets'] += 1
        self._reset_state()

    @property
    def pose(self) -> np.ndarray | None:
        """The pose of the last scan (None before the first, or after a reset)."""
        return self.chain[_POSE:_POSE + 3].copy() if self._stamp is not None else None

    def update(self, scan: Scan) -> EgoMotionEstimate:
        """Estimate the motion for ``scan`` (the steps of the module docstring), without the
        beams the self-mask leaves out (and learning from it) when there is one."""
        t = float(scan.stamp)
        if self._stamp is not None and t == self._stamp:
            return self._none(t, 'scan stamp equals the previous one (skipped)')
        if self._stamp is not None and t < self._stamp:
            self.reset(f'time went backwards ({self._stamp:.3f} -> {t:.3f} s)')
        odo, seg, missing = self.odometry.at_scan(t)
        ox, oy, oth = odo if odo is not None else (0.0, 0.0, 0.0)
        n = scan.ranges.size
        _, cos, sin = beam_table(float(scan.angle_min), float(scan.angle_increment), n)
        local = self.matcher.map
        local.reserve(min(n, self.config.max_points))
        mask = self.self_mask
        if mask is not None:
            mask.fit(scan)
            mask.follow_noise(scan)
            mask_settings, mask_state, masked = mask.settings, mask.state, np.empty(n)
        else:
            mask_settings, mask_state, masked = _NO_MASK
        out = np.empty(_OUT)
        args = [t, scan.ranges, cos, sin, max(scan.range_min, 1e-6), float(scan.range_max),
                abs(float(scan.angle_increment)), odo is not None, ox, oy, oth, seg,
                self.chain, self.settings, self.prior.noise, self.matcher.schedule.distances,
                self.matcher.schedule.settings, *local.buffers, mask_settings, mask_state,
                masked, out]
        _scan_step(*args)
        if out[_O_SOURCE] == _INIT and self.rehearses and not _rehearsed:
            _rehearse(args)
        if mask is not None:
            mask.masked_ranges = masked
            mask.applied = masked if out[_O_MASKED] else None
        previous, self._stamp = self._stamp, t
        return self._estimate(t, out, previous, missing)

    # ------------------------------------------------------------------- internals

    def _estimate(self, t: float, out: np.ndarray, previous: float | None,
                  missing: str) -> EgoMotionEstimate:
        """The estimate of what :func:`_scan_step` found (``out``), its reason and notes."""
        v = out.tolist()
        source = SOURCES[int(v[_O_SOURCE])]
        pose, pose_cov = out[_O_POSE:_O_POSE + 3], out[_O_POSE_COV:_O_POSE_COV + 9]
        if source == SOURCE_INIT:
            reason = 'first scan: pose from odometry' if v[_O_ODOMETRY] else \
                f'first scan: pose at the origin ({missing})'
            self.stats[SOURCE_INIT] += 1
            return EgoMotionEstimate(stamp=t, pose=pose, motion=out[_O_MOTION:_O_MOTION + 3],
                                     covariance=out[_O_COV:_O_COV + 9].reshape(3, 3),
                                     source=source, reason=reason,
                                     n_points=int(v[_O_N_POINTS]),
                                     pose_covariance=pose_cov.reshape(3, 3))
        no_inc = ''
        if v[_O_INC] != _INC_OK:
            no_inc = self._no_increment(v, missing)
            self._note('no odometry', f'scan at {t:.3f} s: no odometry increment '
                       f'({no_inc}): constant-velocity prediction')
        has_inc = v[_O_ODOMETRY] != 0.0
        coasting = source in (SOURCE_ODOMETRY, SOURCE_CONSTANT_VELOCITY)
        if not coasting:
            n_deg = int(v[_O_N_DEG])
            if n_deg and has_inc:
                reason = f'{n_deg} degenerate direction(s): odometry along them'
            elif n_deg:
                reason = (f'{n_deg} degenerate direction(s) and no odometry ({no_inc}): '
                          f'constant-velocity guess along them')
            else:
                reason = 'icp' if has_inc else f'icp without odometry ({no_inc})'
        else:
            why = self._why(v)
            if has_inc:
                reason = f'ICP refused: {why}'
                self._note('icp refused', f'scan at {t:.3f} s: ICP refused ({why}): odometry '
                           f'used')
            else:
                reason = f'ICP refused ({why}) and no odometry ({no_inc}): coasting'
                self._note('coasting', f'scan at {t:.3f} s: ICP refused ({why}) and no '
                           f'odometry ({no_inc}): constant-velocity motion')
            if v[_O_RESEED]:
                reason += '; local map re-seeded from this scan'
                gap = v[_O_DT]
                after = f'{gap:.2f} s since the previous scan, no odometry across' \
                    if not has_inc and 0.0 < self.config.max_gap < gap \
                    else f'{int(v[_O_LOST])} scans without a match'
                self._note('map re-seeded', f'scan at {t:.3f} s: {after}: the local map is '
                           f're-seeded from this scan (the pose chain continues)')
                self.stats['map re-seeded'] += 1
        self.stats[source] += 1
        diag = {}
        if v[_O_MATCHED]:
            diag = dict(inlier_ratio=v[_O_INLIER_RATIO], rms=v[_O_RMS],
                        iterations=int(v[_O_ITERATIONS]), min_eigenvalue=v[_O_MIN_EIG])
        return EgoMotionEstimate(
            stamp=t, pose=pose, motion=out[_O_MOTION:_O_MOTION + 3],
            covariance=out[_O_COV:_O_COV + 9].reshape(3, 3), source=source, reason=reason,
            dt=t - previous, odometry_motion=out[_O_ODOMETRY + 1:_O_ODOMETRY + 4] if has_inc
            else None, n_points=int(v[_O_N_POINTS]), coasting=coasting,
            pose_covariance=pose_cov.reshape(3, 3), **diag)

    def _no_increment(self, v: list, missing: str) -> str:
        """Why there is no odometry increment (``_O_INC``)."""
        code = v[_O_INC]
        if code == _INC_MISSING:
            return missing
        if code == _INC_NO_PREVIOUS:
            return 'no odometry at the previous scan'
        if code == _INC_JUMPED:
            return 'odometry jumped since the previous scan'
        return f'odometry step implies {self._speed(v[_O_INC + 1], v[_O_INC + 2])} (jump?)'

    def _why(self, v: list) -> str:
        """Why the match was not used (``_O_WHY``)."""
        c = self.config
        code = v[_O_WHY]
        if code == _WHY_FEW_POINTS:
            return f'too few valid points ({int(v[_O_N_POINTS])} < {c.min_points})'
        if code == _WHY_SMALL_MAP:
            return f'local map too small ({int(v[_O_WHY + 1])} points)'
        if code == FEW_INLIERS:
            return f'only {int(v[_O_WHY + 1])} points matched'
        if code == LOW_OVERLAP:
            return (f'overlap {100 * v[_O_INLIER_RATIO]:.0f} % < '
                    f'{100 * c.min_inlier_ratio:.0f} %')
        if code == HIGH_RESIDUAL:
            return f'residual {v[_O_RMS]:.3f} m > {c.max_rms:g} m'
        if code == NOT_CONVERGED:
            return 'did not converge'
        if code == NOT_FINITE:
            return 'non-finite result'
        if code == DEGENERATE:
            return 'degenerate in every direction'
        if code == _WHY_TOO_FAST:
            return f'match implies {self._speed(v[_O_WHY + 1], v[_O_WHY + 2])}'
        if code == _WHY_DISAGREES:
            return (f'match disagrees with odometry by {v[_O_WHY + 1]:.2f} m / '
                    f'{math.degrees(v[_O_WHY + 2]):.1f} deg')
        return ''

    def _speed(self, kind: float, speed: float) -> str:
        """A speed beyond the platform's limits (kind 1: translation, 2: rotation)."""
        c = self.config
        if kind == 1:
            return f'{speed:.2f} m/s > {c.max_translation_speed:g} m/s'
        return (f'{math.degrees(speed):.0f} deg/s > '
                f'{math.degrees(c.max_rotation_speed):.0f} deg/s')

    def _reset_state(self) -> None:
        self.matcher.clear()
        self.chain[:] = 0.0
        self._stamp: float | None = None

    def _note(self, kind: str, message: str, level: int = logging.WARNING) -> None:
        """Log ``message``: first time, then at the 10th, 100th, ... time for its kind."""
        self._notes[kind] += 1
        self.stats[f'note: {kind}'] += 1
        n = self._notes[kind]
        if n == 1 or (n >= 10 and math.log10(n).is_integer()):
            log.log(level, '%s%s', message, f' ({n} times so far)' if n > 1 else '')
        else:
            log.debug('%s', message)

    def _none(self, t: float, reason: str) -> EgoMotionEstimate:
        self._note('no pose', f'scan at {t:.3f} s has no pose: {reason}')
        self.stats[SOURCE_NONE] += 1
        nan3 = np.full(3, np.nan)
        return EgoMotionEstimate(stamp=t, pose=nan3, motion=nan3.copy(),
                                 covariance=np.full((3, 3), np.nan), source=SOURCE_NONE,
                                 reason=reason)


#: ``_scan_step``'s self-mask arguments without a self-mask.
_NO_MASK = (np.zeros(0), np.zeros((0, 0)), np.zeros(0))
#: Whether this process has rehearsed a match (:func:`_rehearse`).
_rehearsed: list[bool] = []


def _rehearse(args: list) -> None:
    """The process's first scan, which started a pose chain (``args``: its
    :func:`_scan_step` call), matched once more a little later against the map it seeded,
    on copies of every state it would change (nothing of it is kept): the processor meets
    the match's code with real data here, and the second scan runs at full speed (about
    0.1 ms more for the first scan, once per process)."""
    _rehearsed.append(True)
    copies = [a.copy() if isinstance(a, np.ndarray) and a.flags.writeable else a
              for a in args]
    copies[0] = args[0] + 0.1
    _scan_step(*copies)


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
