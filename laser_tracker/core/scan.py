"""A laser scan as numpy arrays, its beam geometry, and the checks every consumer relies on.

Every module of the pipeline takes a :class:`Scan`; conversion from messages happens once in
``laser_tracker.conversions``. Invalid beams (NaN, inf, below ``range_min``, at or above
``range_max``) are never interpreted as obstacles: :meth:`Scan.valid` says which beams hit
something, :meth:`Scan.free_ranges` how far each beam saw free space.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import lru_cache

import numpy as np


class ScanError(ValueError):
    """A scan that cannot be used at all (the message says why); callers skip it."""


@lru_cache(maxsize=16)
def beam_table(angle_min: float, angle_increment: float, n_beams: int):
    """Cached (angles, cos, sin) for one scan geometry (read-only arrays)."""
    angles = angle_min + angle_increment * np.arange(n_beams)
    table = (angles, np.cos(angles), np.sin(angles))
    for a in table:
        a.setflags(write=False)
    return table


@dataclass
class Scan:
    """One sweep: ``ranges[i]`` along ``angle_min + i * angle_increment`` in the laser frame.

    ``stamp`` is the acquisition time of the first beam in seconds. Ranges are metres; values
    that are not finite or lie outside ``[range_min, range_max)`` mean "no return".
    """

    stamp: float
    ranges: np.ndarray
    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float
    time_increment: float = 0.0
    scan_time: float = 0.0
    frame_id: str = 'laser'
    stamp_ns: int | None = None   # the exact message stamp (integer ns), when known

    def __post_init__(self):
        self.ranges = np.asarray(self.ranges, dtype=np.float64).ravel()
        if not self.ranges.flags.writeable:      # the kernels are compiled for writable ones
            self.ranges = self.ranges.copy()
        if self.ranges.size == 0:
            raise ScanError('scan has no beams')
        if not np.isfinite(self.stamp) or self.stamp < 0:
            raise ScanError(f'scan stamp must be finite and not negative: {self.stamp!r}')
        if not (np.isfinite(self.angle_increment) and self.angle_increment != 0.0):
            raise ScanError(f'angle_increment must be finite and non-zero, '
                            f'got {self.angle_increment!r}')
        if not np.isfinite(self.angle_min):
            raise ScanError(f'angle_min is not finite: {self.angle_min!r}')
        if not (np.isfinite(self.range_max) and self.range_max > 0):
            raise ScanError(f'range_max must be positive and finite, got {self.range_max!r}')
        if not np.isfinite(self.range_min) or self.range_min < 0:
            self.range_min = 0.0

    @property
    def n_beams(self) -> int:
        return int(self.ranges.size)

    @property
    def angles(self) -> np.ndarray:
        return beam_table(float(self.angle_min), float(self.angle_increment), self.n_beams)[0]

    def valid(self) -> np.ndarray:
        """Beams that returned from an obstacle within the sensor's range."""
        r = self.ranges
        with np.errstate(invalid='ignore'):
            return np.isfinite(r) & (r >= max(self.range_min, 1e-6)) & (r < self.range_max)

    def silent(self) -> np.ndarray:
        """Beams that returned nothing (REP 117: +inf, NaN, a no-return code below
        ``range_min``, a reading at ``range_max``): not -inf (something too close)."""
        r = self.ranges
        with np.errstate(invalid='ignore'):
            return ~(self.valid() | (r == -np.inf))

    def with_no_returns_as_inf(self) -> Scan:
        """A copy whose no-return codes (0 and readings below ``range_min``, which older
        drivers write) read +inf, as a driver following REP 117 writes them (-inf stays)."""
        r = self.ranges.copy()
        with np.errstate(invalid='ignore'):
            r[(r >= 0) & (r < self.range_min)] = np.inf
        return dataclasses.replace(self, ranges=r)

    def every_nth_beam(self, step: int) -> Scan:
        """The scan a scanner with ``step`` times fewer beams over the same field would have
        made: every ``step``-th beam, from the first."""
        if step < 1:
            raise ValueError(f'beam step must be at least 1, got {step}')
        return dataclasses.replace(self, ranges=self.ranges[::step].copy(),
                                   angle_increment=self.angle_increment * step,
                                   time_increment=self.time_increment * step)

    def mirrored(self) -> Scan:
        """The scan of a scanner hung upside down, as the same scanner turned right side up
        about its x axis would make it: the beam at angle ``a`` points along ``-a`` there.
        The beams come in the other order so that the angles still run as the increment
        says (the pipeline does not use the beams' times)."""
        last = self.angle_min + (self.n_beams - 1) * self.angle_increment
        return dataclasses.replace(self, ranges=self.ranges[::-1].copy(), angle_min=-last)

    def points(self, max_range: float | None = None) -> np.ndarray:
        """Cartesian end points (M, 2) of the valid beams, in the laser frame."""
        mask = self.valid()
        if max_range is not None:
            mask &= self.ranges <= max_range
        _, cos, sin = beam_table(float(self.angle_min), float(self.angle_increment), self.n_beams)
        r = self.ranges[mask]
        return np.column_stack((r * cos[mask], r * sin[mask]))

    def free_ranges(self, max_free: float | None = None) -> np.ndarray:
        """How far along each beam space was seen free (metres).

        A return frees space up to the hit; a no-return reading (inf or >= range_max) frees
        space up to ``max_free`` (default ``range_max``); NaN and negative readings free nothing.
        """
        limit = self.range_max if max_free is None else min(max_free, self.range_max)
        r = self.ranges
        out = np.zeros_like(r)
        valid = self.valid()
        out[valid] = np.minimum(r[valid], limit)
        with np.errstate(invalid='ignore'):
            no_return = np.isposinf(r) | (np.isfinite(r) & (r >= self.range_max))
        out[no_return] = limit
        return out


#: Largest relative change of the angle between beams, and share of the field of view lost
#: at its ends, for which two scans count as one scanner's beams jittering rather than a
#: scanner set to another resolution or field of view: drivers that publish each
#: revolution's measurements as they came (YDLIDAR's ROS 2 driver, RPLIDAR without
#: ``angle_compensate``) vary the beam count by a few in a thousand and move the ends by a
#: beam, a reconfigured scanner changes its resolution by a factor of 2 or its field by
#: degrees.
SAME_BEAMS_TOLERANCE = 0.05

#: A scan's beams: (angle_min, angle_increment, beam count).
BeamGeometry = tuple


def geometry_of(scan: Scan) -> BeamGeometry:
    return (float(scan.angle_min), float(scan.angle_increment), scan.n_beams)


def beams_jitter(old: BeamGeometry, new: BeamGeometry,
                 tolerance: float = SAME_BEAMS_TOLERANCE) -> bool:
    """Whether ``new`` is ``old``'s scanner with its beams jittering (see
    ``SAME_BEAMS_TOLERANCE``): the same sense of turn, the increment within ``tolerance``
    of ``old``'s, and ``new``'s field covering ``old``'s but for that share of it."""
    a0, inc, n = old
    b0, binc, m = new
    if not inc * binc > 0 or abs(binc / inc - 1.0) > tolerance:
        return False
    lo, hi = sorted((a0, a0 + inc * (n - 1)))
    blo, bhi = sorted((b0, b0 + binc * (m - 1)))
    span = hi - lo
    return span > 0 and min(hi, bhi) - max(lo, blo) >= (1.0 - tolerance) * span


def nearest_beams(old: BeamGeometry, new: BeamGeometry) -> tuple[np.ndarray, np.ndarray]:
    """Per beam of ``new``: the index of ``old``'s beam nearest to it in angle, and whether
    it lies within half a beam of ``old``'s field (else the index is meaningless)."""
    a0, inc, n = old
    angles = beam_table(*new)[0]
    nearest = np.rint((angles - a0) / inc)
    inside = (nearest >= 0) & (nearest < n)
    return np.where(inside, nearest, 0).astype(np.intp), inside
