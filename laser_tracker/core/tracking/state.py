"""The tracker's state: every live hypothesis as one record of a numpy structured array.

One gather moves every field of the selected hypotheses at once (a split, a removal, a
merge), so the per-frame cost does not grow with the number of fields; each field is a view
(``hyp.weight``, ``hyp.state``, ...).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

#: What created a hypothesis (``origin``): motion blobs (the paper), a person detection, or a
#: person detection standing in space seen free before (someone who walked in).
MOTION, PERSON, PERSON_WALKED_IN = 0, 1, 2

#: The fields of a hypothesis (the covariance ``P`` follows the numbers, its size set by the
#: filter; the flags come last: with the record padded to 8 bytes every number is aligned,
#: which numpy's arithmetic on the fields needs to be fast).
FIELDS = (
    ('track_id', np.int64, ()),       # unique among the live hypotheses
    ('state', np.float64, (4,)),      # px, py, vx, vy valid at t_state (kalman.TrackFilter)
    ('t_state', np.float64, ()),      # stamp of the last supporting measurement
    ('position', np.float64, (2,)),   # the estimate at the current frame
    ('weight', np.float64, ()),       # 0..100 (Eq. 3)
    ('samples', np.int64, ()),        # the creation pair, then one per supporting measurement
    ('born', np.float64, ()),         # creation stamp
    ('t_still', np.float64, ()),      # last frame measured standing (-inf: never)
    ('start', np.float64, (2,)),      # where it was created (the later blob of its pair)
    ('start_local', np.float64, (2,)),  # ... in the scanner's frame of that moment
    ('person_samples', np.int64, ()),  # supports by person detections
    ('pair_samples', np.int64, ()),   # ... of them by two legs
    ('spread', np.float64, (2,)),     # least and largest leg separation seen (NaN: none)
)
FLAGS = (
    ('confirmed', np.bool_, ()),
    ('supported', np.bool_, ()),      # a blob or person detection supported it this frame
    ('stopped', np.bool_, ()),        # held by a segment where it stands, this frame
    ('origin', np.int8, ()),          # MOTION, PERSON or PERSON_WALKED_IN
)


@functools.cache
def hypothesis_dtype(dim: int) -> np.dtype:
    """The record of one hypothesis whose filter has a ``dim``-dimensional state."""
    return np.dtype([(name, kind, shape) for name, kind, shape in FIELDS]
                    + [('P', np.float64, (dim, dim))]
                    + [(name, kind, shape) for name, kind, shape in FLAGS], align=True)


class Hypotheses:
    """All live hypotheses (``rows``: a structured array of :func:`hypothesis_dtype`).

    Each field of :data:`FIELDS` and :data:`FLAGS` is an attribute (a view: assigning to it
    writes the rows); ``velocity`` is ``state[:, 2:]`` and ``P`` the filter's covariance
    (k, d, d). Rows are gathered and joined as raw records (numpy's copies of structured
    records field by field are several times slower).
    """

    __slots__ = ('rows', '_opaque_rows')

    def __init__(self, rows: np.ndarray, opaque: np.ndarray | None = None):
        self.rows = rows
        self._opaque_rows = opaque        # the same records as opaque items, once needed

    @classmethod
    def empty(cls, dim: int, n: int = 0) -> Hypotheses:
        """``n`` hypotheses, zero in every field (none: one shared empty set, as nothing can
        be written into it)."""
        return cls(np.zeros(n, hypothesis_dtype(dim))) if n else _none(dim)

    def __len__(self) -> int:
        return int(self.rows.shape[0])

    @property
    def dim(self) -> int:
        return self.rows.dtype['P'].shape[0]

    def take(self, index) -> Hypotheses:
        """The hypotheses at ``index`` (a mask or indices), as a copy."""
        return _records(self.opaque()[index], self.rows.dtype)

    @staticmethod
    def concat(parts: list[Hypotheses], dim: int) -> Hypotheses:
        parts = [p for p in parts if p.rows.shape[0]]
        if not parts:
            return Hypotheses.empty(dim)
        if len(parts) == 1:
            return parts[0]
        return _records(np.concatenate([p.opaque() for p in parts]), parts[0].rows.dtype)

    def opaque(self) -> np.ndarray:
        """The records as raw bytes (one opaque item each), a view."""
        if self._opaque_rows is None:
            rows = self.rows
            self._opaque_rows = rows.view(_opaque(rows.dtype.itemsize))
        return self._opaque_rows

    @property
    def velocity(self) -> np.ndarray:
        return self.rows['state'][:, 2:]

    def is_person(self, kind_samples: int) -> np.ndarray:
        """Mask: hypotheses of kind person (supported by ``kind_samples`` person
        detections: ``hypotheses.person_kind_samples``)."""
        return self.rows['person_samples'] >= kind_samples


def _records(opaque: np.ndarray, dtype: np.dtype) -> Hypotheses:
    """The hypotheses of raw records (a new contiguous array of opaque items) of ``dtype``
    (``frombuffer``: a view without ``view``'s check of the fields, which costs more than
    the copy)."""
    return Hypotheses(np.frombuffer(opaque, dtype), opaque)


@functools.cache
def _none(dim: int) -> Hypotheses:
    return Hypotheses(np.zeros(0, hypothesis_dtype(dim)))


@functools.cache
def _opaque(size: int) -> np.dtype:
    return np.dtype((np.void, size))


def _field(name: str) -> property:
    def get(self):
        return self.rows[name]

    def set(self, value):
        self.rows[name] = value
    return property(get, set)


for _name, _kind, _shape in FIELDS + FLAGS + (('P', np.float64, None),):
    setattr(Hypotheses, _name, _field(_name))


@dataclass
class Tracks:
    """What the tracker reports at one frame (the ``tracks`` topic): one row per hypothesis.

    ``covariance`` (k, 2, 2): of ``position``; ``moving``: speed at least
    ``hypotheses.moving_speed`` and not stopped; ``kind``: ``person`` once person detections
    supported it ``person_kind_samples`` times, else ``object`` (found by its motion).
    """

    stamp: float
    track_id: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    covariance: np.ndarray
    weight: np.ndarray
    samples: np.ndarray
    confirmed: np.ndarray
    moving: np.ndarray
    kind: np.ndarray

    def __len__(self) -> int:
        return int(self.track_id.size)

    def select(self, mask) -> Tracks:
        return Tracks(self.stamp, *(getattr(self, f)[mask] for f in (
            'track_id', 'position', 'velocity', 'covariance', 'weight', 'samples',
            'confirmed', 'moving', 'kind')))
