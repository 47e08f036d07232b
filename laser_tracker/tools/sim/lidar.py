"""Range scanner models: beam geometry, timing, and measurement errors of a SICK LMS 2xx
(:class:`Lidar`) and of a Hokuyo-class scanner (:class:`Hokuyo`, at the end).

Geometry: 180 deg (or 100 deg) in front of the scanner, beams from ``-fov/2`` to ``+fov/2``
(``angle_min = -pi/2`` for 180 deg) at 0.5 deg (361 beams) or 1 deg (181 beams), x forward.

Timing: the mirror turns at 75 Hz, so consecutive beams are ``time_increment =
angle_increment / (2 pi) / 75`` s apart (18.5 us at 0.5 deg) and a 180 deg sweep takes 6.7 ms;
``scan_time`` is the mirror period 1/75 s (as the ROS SICK drivers report it). Scans are
delivered at ``scan_rate_hz`` (the serial link limits it: 361 beams at 38,400 baud give
about 4.8 Hz, the paper's rate); a scan starts on a mirror revolution, so stamps are
multiples of 1/75 s. A scan's stamp is the acquisition time of its first beam; it reaches the
host ``receive_delay`` later (the bag's receive time).

Readings: the true range plus Gaussian noise (``noise_sigma``), rounded to the unit of the
range mode (1 mm in the 8 m mode, 1 cm in the 80 m mode). Where nothing returns within range,
and on a dropout (a beam that loses its echo on a dark or grazing surface), the reading is
exactly ``range_max``, and the message's ``range_max`` equals it, so consumers see "no return"
(``Scan.valid()`` is False, ``Scan.free_ranges()`` treats it as free up to range_max). A
spurious return (dust, a mixed pixel) is a reading uniformly distributed between 0.1 m and
the true range.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from laser_tracker.config import param

MIRROR_HZ = 75.0


@dataclass(frozen=True)
class ScannerMount:
    """Where a simulated scanner sits on the platform, and its frame (both scanner models)."""

    mount_x: float = param(0.0, 'Scanner position on the platform, forward (m).',
                           min=-2.0, max=2.0)
    mount_y: float = param(0.0, 'Scanner position on the platform, left (m).',
                           min=-2.0, max=2.0)
    mount_yaw: float = param(0.0, 'Scanner yaw on the platform (rad).', min=-math.pi,
                             max=math.pi)
    frame_id: str = param('laser', 'Frame of the scans.')


@dataclass(frozen=True)
class LidarConfig(ScannerMount):
    """The simulated SICK LMS (section ``sim.lidar``)."""

    fov_deg: float = param(180.0, 'Field of view (deg), centred on the x axis.',
                           choices=(100.0, 180.0))
    resolution_deg: float = param(0.5, 'Angle between beams (deg): 361 or 181 beams over 180 '
                                  'deg.', choices=(0.5, 1.0))
    range_max: float = param(8.0, 'Range mode (m): 8 (mm unit) or 80 (cm unit); readings at '
                             'range_max mean no return.', choices=(8.0, 80.0))
    range_min: float = param(0.0, 'Smallest range the scanner reports (m).', min=0.0, max=1.0)
    noise_sigma: float = param(0.01, 'Standard deviation of the range noise (m).',
                               min=0.0, max=0.5)
    dropout_probability: float = param(0.001, 'Probability that a beam that hits something '
                                       'reports no return.', min=0.0, max=0.5)
    spurious_probability: float = param(0.0005, 'Probability that a beam reports a random '
                                        'short range (dust, mixed pixel).', min=0.0, max=0.5)
    scan_rate_hz: float = param(5.0, 'Scans delivered per second (serial-link limited; the '
                                'paper: 143 scans in 30 s).', min=0.1, max=MIRROR_HZ)
    receive_delay: float = param(0.19, 'Time from the first beam to the scan reaching the host '
                                 '(s): 732 bytes at 38,400 baud.', min=0.0, max=1.0)


class Lidar:
    """Beam geometry and measurement model of one configuration."""

    def __init__(self, config: LidarConfig | None = None):
        self.config = c = config or LidarConfig()
        self.n_beams = int(round(c.fov_deg / c.resolution_deg)) + 1
        self.angle_increment = math.radians(c.resolution_deg)
        self.angle_min = -math.radians(c.fov_deg) / 2.0
        self.angles = self.angle_min + self.angle_increment * np.arange(self.n_beams)
        self.scan_time = 1.0 / MIRROR_HZ
        self.time_increment = self.angle_increment / (2.0 * math.pi) / MIRROR_HZ
        self.beam_offsets = self.time_increment * np.arange(self.n_beams)
        self.unit = 0.001 if c.range_max <= 8.5 else 0.01

    def beams(self, rng: np.random.Generator) -> tuple[float, float, np.ndarray, np.ndarray]:
        """One scan's beams: ``(angle_min, angle_increment, angles, time offsets)``, the
        same in every scan."""
        return self.angle_min, self.angle_increment, self.angles, self.beam_offsets

    def scan_stamps(self, t_start: float, duration: float) -> np.ndarray:
        """Start times of the scans in ``[t_start, t_start + duration)``, on mirror revolutions."""
        c = self.config
        count = int(math.floor(duration * c.scan_rate_hz + 1e-9))
        revolutions = np.round(np.arange(count) * MIRROR_HZ / c.scan_rate_hz)
        t0 = math.ceil(t_start * MIRROR_HZ - 1e-9)
        return (t0 + revolutions) / MIRROR_HZ

    def measure(self, true_ranges: np.ndarray, rng: np.random.Generator, incidence=None,
                increment: float | None = None):
        """Readings for the true ranges of one sweep (``inf`` = nothing hit); the LMS model
        ignores the angle of ``incidence`` and the sweep's beam ``increment``.

        Returns ``(ranges, returned)``: the readings, and which beams report the object they
        hit (not dropped, not spurious, within range). Draws a fixed number of random values
        per beam, so one scan's randomness never shifts another's.
        """
        c = self.config
        n = true_ranges.size
        noise = rng.standard_normal(n) * c.noise_sigma
        u_drop, u_spur, u_len = rng.random(n), rng.random(n), rng.random(n)
        in_range = np.isfinite(true_ranges) & (true_ranges < c.range_max)
        r = np.where(in_range, true_ranges, c.range_max) + noise
        dropped = in_range & (u_drop < c.dropout_probability)
        spurious = (u_spur < c.spurious_probability) & ~dropped
        reach = np.minimum(np.where(in_range, true_ranges, c.range_max), c.range_max)
        r = np.where(spurious, 0.1 + u_len * np.maximum(reach - 0.1, 0.0), r)
        r = np.round(r / self.unit) * self.unit
        r = np.clip(r, max(c.range_min, self.unit), c.range_max)
        no_return = (~in_range & ~spurious) | dropped | (r >= c.range_max)
        r = np.where(no_return, c.range_max, r)
        returned = in_range & ~dropped & ~spurious & (r < c.range_max)
        return r, returned


# ---------------------------------------------------------------------------------- Hokuyo
@dataclass(frozen=True)
class HokuyoConfig(ScannerMount):
    """A simulated Hokuyo-class scanner (section ``sim.hokuyo``), as in the real robots'
    recordings: 768 beams of 2 pi / 1024 rad over 270 deg, 11 m, 1 mm unit.

    Timing: the head turns at ``revolution_hz`` with ``steps_per_revolution`` steps, so beams
    are ``1 / (revolution_hz * steps)`` s apart (65 us: a 768-beam sweep takes 50 ms) and
    each beam is taken at its own time. A scan is delivered every ``skip + 1`` revolutions
    (7.5 Hz); ``scan_time`` is the time between scans, as the drivers report it with a skip.

    Readings: as the LMS model (Gaussian noise, rounding to the unit, random dropouts and
    spurious short returns), plus dropouts at grazing incidence (beyond ``grazing_deg``,
    with a probability that rises to ``grazing_dropout_probability`` over
    ``grazing_ramp_deg``); a beam without a return reads ``no_return``: 0, an error code
    below ``range_min`` as the Hokuyo drivers of the real recordings report it (the beam
    frees nothing), ``range_max``, inf, or ``mixed``: inf, NaN (``no_return_nan``) or 0
    (``no_return_zero``) at random, as a REP 117 driver that also reports its error codes.
    """

    beams: int = param(768, 'Number of beams, centred on the x axis.', min=3, max=4096)
    steps_per_revolution: int = param(1024, 'Angular steps per head revolution; the angle '
                                      'between beams is 2 pi / steps.', min=360, max=4096)
    revolution_hz: float = param(15.0, 'Head revolutions per second.', min=1.0, max=100.0)
    skip: int = param(1, 'Revolutions skipped between delivered scans (1: every other one, '
                      '7.5 Hz).', min=0, max=9)
    range_max: float = param(11.0, 'Largest range reported (m).', min=1.0, max=60.0)
    range_min: float = param(0.03, 'Smallest valid range (m); error codes lie below it.',
                             min=0.0, max=1.0)
    unit: float = param(0.001, 'Resolution of the readings (m).', min=1e-4, max=0.05)
    noise_sigma: float = param(0.015, 'Standard deviation of the range noise (m).',
                               min=0.0, max=0.5)
    dropout_probability: float = param(0.002, 'Probability that a beam that hits something '
                                       'reports no return.', min=0.0, max=0.5)
    spurious_probability: float = param(0.0005, 'Probability that a beam reports a random '
                                        'short range (dust, mixed pixel).', min=0.0, max=0.5)
    grazing_deg: float = param(80.0, 'Incidence angle (deg from the surface normal) beyond '
                               'which a return may be lost.', min=45.0, max=90.0)
    grazing_dropout_probability: float = param(0.5, 'Probability that a beam hitting beyond '
                                               'grazing_deg (+ grazing_ramp_deg) reports no '
                                               'return.', min=0.0, max=1.0)
    grazing_ramp_deg: float = param(0.0, 'Degrees beyond grazing_deg over which the '
                                    'grazing dropout probability rises linearly from 0 '
                                    '(0: a step at grazing_deg).', min=0.0, max=45.0)
    grazing_reference_range: float = param(
        0.0, 'Range (m) at which grazing_deg holds; nearer surfaces return at more grazing '
        'angles, as the returned power grows with cos(incidence) / range^2 (the limit\'s '
        'cosine scales with (range / reference)^2). 0 = the same limit at every range.',
        min=0.0, max=60.0)
    no_return: str = param('zero', 'Reading of a beam without a return.',
                           choices=('zero', 'range_max', 'inf', 'mixed'))
    no_return_nan: float = param(0.0, 'With no_return mixed: fraction of the beams without a '
                                 'return that read NaN.', min=0.0, max=1.0)
    no_return_zero: float = param(0.0, 'With no_return mixed: fraction that read 0.',
                                  min=0.0, max=1.0)
    receive_delay: float = param(0.07, 'Time from the first beam to the scan reaching the host '
                                 '(s): the rest of the revolution and the USB transfer.',
                                 min=0.0, max=1.0)
    beam_width: float = param(0.0, 'Width of the beam (m) where it leaves the scanner: a beam '
                              'that passes the edge of a nearer surface within it returns a '
                              'mixed range, short of the surface behind by up to '
                              'mixed_shortfall of the range step (0: none).', min=0.0,
                              max=0.2)
    mixed_shortfall: float = param(0.1, 'Largest shortfall of a mixed return, as a fraction '
                                   'of the range step at the edge.', min=0.0, max=1.0)
    beam_count_jitter: int = param(
        0, 'A scan carries up to this many beams more or fewer than beams, spread over the '
        'same field (the increment recomputed to fit), drawn anew for every scan: drivers '
        'that publish each revolution\'s samples as they came (YDLIDAR\'s ROS 2 driver, '
        'RPLIDAR without angle_compensate), whose count follows the head\'s speed. 0 = the '
        'same beams in every scan.', min=0, max=100)


class Hokuyo:
    """Beam geometry, timing and measurement model of a :class:`HokuyoConfig`; the same
    interface as :class:`Lidar`."""

    def __init__(self, config: HokuyoConfig | None = None):
        self.config = c = config or HokuyoConfig()
        self.n_beams = int(c.beams)
        self.angle_increment = 2.0 * math.pi / c.steps_per_revolution
        self.angle_min = -(self.n_beams // 2) * self.angle_increment
        self.angles = self.angle_min + self.angle_increment * np.arange(self.n_beams)
        self.scan_rate_hz = c.revolution_hz / (c.skip + 1)
        self.scan_time = 1.0 / self.scan_rate_hz
        self.time_increment = 1.0 / (c.revolution_hz * c.steps_per_revolution)
        self.beam_offsets = self.time_increment * np.arange(self.n_beams)
        self.unit = c.unit
        self.no_return_reading = {'zero': 0.0, 'range_max': c.range_max,
                                  'inf': math.inf, 'mixed': math.inf}[c.no_return]

    def beams(self, rng: np.random.Generator) -> tuple[float, float, np.ndarray, np.ndarray]:
        """One scan's beams: ``(angle_min, angle_increment, angles, time offsets)``; with
        ``beam_count_jitter`` a count drawn from ``rng`` over the same field and sweep time."""
        jitter = self.config.beam_count_jitter
        if not jitter:
            return self.angle_min, self.angle_increment, self.angles, self.beam_offsets
        n = self.n_beams + int(rng.integers(-jitter, jitter + 1))
        scale = (self.n_beams - 1) / (n - 1)
        k = np.arange(n)
        return (self.angle_min, self.angle_increment * scale,
                self.angle_min + self.angle_increment * scale * k,
                self.time_increment * scale * k)

    def scan_stamps(self, t_start: float, duration: float) -> np.ndarray:
        """Start times of the scans in ``[t_start, t_start + duration)``, on revolutions."""
        c = self.config
        count = int(math.floor(duration * self.scan_rate_hz + 1e-9))
        first = math.ceil(t_start * c.revolution_hz - 1e-9)
        return (first + (c.skip + 1) * np.arange(count)) / c.revolution_hz

    def measure(self, true_ranges: np.ndarray, rng: np.random.Generator,
                incidence: np.ndarray | None = None, increment: float | None = None):
        """Readings for the true ranges of one sweep (``inf`` = nothing hit); ``incidence``
        (N,) is each hit's angle from the surface normal (rad), None for head-on;
        ``increment`` the sweep's angle between beams (rad; None: the nominal one; a
        jittering beam count changes it), which sets how many beams an edge partly blocks.

        Returns ``(ranges, returned)`` as :meth:`Lidar.measure` (a mixed return beside a
        nearer edge is not a return of the surface it was aimed at); draws a fixed number of
        random values per beam.
        """
        c = self.config
        n = true_ranges.size
        noise = rng.standard_normal(n) * c.noise_sigma
        u_drop, u_spur, u_len, u_graze = (rng.random(n), rng.random(n), rng.random(n),
                                          rng.random(n))
        in_range = np.isfinite(true_ranges) & (true_ranges < c.range_max)
        if incidence is None:
            p_graze = np.zeros(n)
        else:
            limit = math.radians(c.grazing_deg)
            if c.grazing_reference_range > 0:
                scale = np.minimum(np.where(in_range, true_ranges, np.inf)
                                   / c.grazing_reference_range, 1.0) ** 2
                limit = np.arccos(math.cos(limit) * scale)
            with np.errstate(invalid='ignore'):
                beyond = np.asarray(incidence) - limit
                ramp = np.clip(beyond / math.radians(c.grazing_ramp_deg), 0.0, 1.0) \
                    if c.grazing_ramp_deg > 0 else (beyond > 0).astype(float)
            p_graze = np.where(np.isfinite(ramp), ramp, 0.0) * c.grazing_dropout_probability
        dropped = in_range & ((u_drop < c.dropout_probability) | (u_graze < p_graze))
        spurious = (u_spur < c.spurious_probability) & ~dropped
        reach = np.where(in_range, true_ranges, c.range_max)
        r = np.where(in_range, true_ranges, c.range_max) + noise
        mixed = np.zeros(n, bool)
        if c.beam_width > 0:
            shortfall = mixed_shortfall(true_ranges, increment or self.angle_increment,
                                        c.beam_width,
                                        rng.random(n) * c.mixed_shortfall)
            r = r - shortfall
            mixed = shortfall > 0
        r = np.where(spurious, 0.1 + u_len * np.maximum(reach - 0.1, 0.0), r)
        r = np.round(r / self.unit) * self.unit
        r = np.clip(r, max(c.range_min, self.unit), c.range_max)
        no_return = (~in_range & ~spurious) | dropped | (r >= c.range_max)
        r = np.where(no_return, self.no_return_reading, r)
        if c.no_return == 'mixed':
            u_code = rng.random(n)
            r = np.where(no_return & (u_code < c.no_return_nan), np.nan, r)
            r = np.where(no_return & (u_code >= c.no_return_nan)
                         & (u_code < c.no_return_nan + c.no_return_zero), 0.0, r)
        returned = in_range & ~dropped & ~spurious & ~no_return & ~mixed
        return r, returned


#: A range step (m) whose nearer side is an edge that partly blocks the beams beside it.
EDGE_STEP = 0.3


def mixed_shortfall(true_ranges: np.ndarray, increment: float, width: float,
                    fraction: np.ndarray) -> np.ndarray:
    """Per beam, how much short of its true range a beam partly blocked by a nearer edge
    reads: ``fraction`` of the range step, for the beams on the far side of each step of
    ``EDGE_STEP`` or more that lie within ``width`` of the edge at its range (0 elsewhere).
    Written apart from the tracker's mask (``core.self_mask``) so that the simulator tests
    that rule rather than repeats it."""
    n = true_ranges.size
    out = np.zeros(n)
    finite = np.isfinite(true_ranges)
    for i in np.flatnonzero(finite[:-1] & finite[1:]):
        a, b = true_ranges[i], true_ranges[i + 1]
        if abs(a - b) < EDGE_STEP:
            continue
        near = min(a, b)
        span = int(width / (near * increment))
        far = range(i + 1, min(n, i + 1 + span)) if a < b else range(i, max(-1, i - span), -1)
        for k in far:
            if finite[k] and true_ranges[k] - near >= EDGE_STEP:
                out[k] = max(out[k], fraction[k] * (true_ranges[k] - near))
    return out


def make_scanner(config):
    """The scanner model of a :class:`LidarConfig` (SICK LMS) or :class:`HokuyoConfig`."""
    if isinstance(config, HokuyoConfig):
        return Hokuyo(config)
    return Lidar(config)
