"""A SICK LMS 2xx range scanner model: beam geometry, timing, and its measurement errors.

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
class LidarConfig:
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
    mount_x: float = param(0.0, 'Scanner position on the platform, forward (m).',
                           min=-2.0, max=2.0)
    mount_y: float = param(0.0, 'Scanner position on the platform, left (m).',
                           min=-2.0, max=2.0)
    mount_yaw: float = param(0.0, 'Scanner yaw on the platform (rad).', min=-math.pi,
                             max=math.pi)
    frame_id: str = param('laser', 'Frame of the scans.')


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

    def scan_stamps(self, t_start: float, duration: float) -> np.ndarray:
        """Start times of the scans in ``[t_start, t_start + duration)``, on mirror revolutions."""
        c = self.config
        count = int(math.floor(duration * c.scan_rate_hz + 1e-9))
        revolutions = np.round(np.arange(count) * MIRROR_HZ / c.scan_rate_hz)
        t0 = math.ceil(t_start * MIRROR_HZ - 1e-9)
        return (t0 + revolutions) / MIRROR_HZ

    def measure(self, true_ranges: np.ndarray, rng: np.random.Generator):
        """Readings for the true ranges of one sweep (``inf`` = nothing hit).

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
