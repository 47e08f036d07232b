"""Identity: track ids through splits, merges and short losses.

* **Ids** count up and are unique among the live hypotheses (a reset keeps counting).
* **Split.** The copy supported by the blob nearest the prediction continues the parent
  (its id, samples and confirmation); the other copies get new ids and restart at one sample
  (they carry the parent's velocity and weight but must earn their own confirmation).
* **Merge** (paper Sec. 8, duplicates): hypotheses within ``merge_distance`` of each other
  whose velocities differ by less than ``merge_speed`` are one target (chains included). The
  group keeps the state of its best-supported member (supported now, then weight, then
  samples) and the identity of its oldest confirmed member (else its oldest member), so a
  person whose leg hypotheses split and merge again keeps one id.
* **Resume** (``resume_time``, beyond the paper): a hypothesis confirmed within
  ``resume_time`` of the loss of a confirmed track of the same kind, within
  ``resume_radius`` of where that track was last seen, takes its id (nearest pairs first,
  each lost track once): a target lost for a moment keeps its identity.
"""
from __future__ import annotations

import numpy as np

from laser_tracker.core.geometry import pairwise_distances
from laser_tracker.core.tracking.role import Role
from laser_tracker.core.tracking.state import MOTION, PERSON, Hypotheses

#: A confirmed track lost recently (``resume_time``): its id, when and where it was lost, and
#: whether it was a person.
LOST = np.dtype([('track_id', np.int64), ('stamp', np.float64), ('position', np.float64, (2,)),
                 ('person', np.bool_)])


class Identity(Role):
    """Ids, splits, merges and resumed tracks (see the module docstring)."""

    def __init__(self, config, filter, stats: dict):
        super().__init__(config, filter, stats)
        self.next_id = 1
        self.reset()

    def reset(self) -> None:
        """Forget the lost tracks (ids keep counting up)."""
        self.lost = np.zeros(0, LOST)

    def new_ids(self, n: int) -> np.ndarray:
        ids = np.arange(self.next_id, self.next_id + n, dtype=np.int64)
        self.next_id += n
        return ids

    def split(self, copies: Hypotheses, parent: np.ndarray, distance: np.ndarray) -> None:
        """``copies`` of the hypotheses ``parent`` (sorted), each at ``distance`` from its
        parent's prediction: all but the nearest copy of each parent become new hypotheses."""
        if parent.size < 2 or not (parent[1:] == parent[:-1]).any():
            return
        order = np.lexsort((distance, parent))
        extra = np.zeros(parent.size, bool)
        extra[order[1:]] = parent[order][1:] == parent[order][:-1]
        n_extra = int(extra.sum())
        rows = copies.rows
        rows['track_id'][extra] = self.new_ids(n_extra)
        rows['samples'][extra] = 1
        rows['confirmed'][extra] = False
        self.stats['splits'] += n_extra
        self.stats['created'] += n_extra

    def merge(self, hyp: Hypotheses) -> Hypotheses:
        """The hypotheses with each group of duplicates collapsed into one."""
        c = self.config
        k = len(hyp)
        if k < 2 or c.merge_distance <= 0:
            return hyp
        close = _squared_distances(hyp.position) <= c.merge_distance ** 2
        if np.count_nonzero(close) == k:          # only the diagonal: nothing to merge
            return hyp
        close &= _squared_distances(hyp.velocity) <= c.merge_speed ** 2
        if np.count_nonzero(close) == k:
            return hyp
        a, b = np.nonzero(close)
        pair = a < b
        group = _components(k, a[pair], b[pair])
        rows = hyp.rows
        # State: the best-supported member (supported now, then weight, then samples).
        keep = _first_of_group(group, np.lexsort((-rows['samples'], -rows['weight'],
                                                  ~rows['supported'])))
        # Identity: the oldest confirmed member, else the oldest member (smallest id).
        ident_key = np.lexsort((rows['track_id'], ~rows['confirmed']))
        irank = np.empty(k, np.intp)
        irank[ident_key] = np.arange(k)
        ibest = np.full(k, k, np.intp)
        np.minimum.at(ibest, group, irank)
        donor = ident_key[ibest[group]]          # row whose identity each row's group keeps
        samples = np.zeros(k, np.int64)
        np.maximum.at(samples, group, rows['samples'])
        # A group with any member not started by a person standing where something always
        # stood carries no such restriction.
        open_ = np.zeros(k, bool)
        np.logical_or.at(open_, group, rows['origin'] != PERSON)
        kept = np.flatnonzero(keep)
        out = hyp.take(kept)
        src = donor[kept]
        merged = out.rows
        for name in ('track_id', 'born', 'start', 'start_local'):
            merged[name] = rows[name][src]
        merged['confirmed'] |= rows['confirmed'][src]
        merged['samples'] = samples[group[kept]]
        merged['origin'] = np.where(open_[group[kept]], MOTION, PERSON)
        self.stats['merged'] += int(k - kept.size)
        return out

    def remember_lost(self, gone: Hypotheses, t: float) -> None:
        """Keep the confirmed tracks among ``gone`` (just removed) for ``resume_time``."""
        c = self.config
        if c.resume_time <= 0:
            return
        lost = self.lost[self.lost['stamp'] >= t - c.resume_time]
        gone = gone.take(gone.confirmed)
        if len(gone):
            rows = np.zeros(len(gone), LOST)
            rows['track_id'], rows['stamp'], rows['position'] = gone.track_id, t, gone.position
            rows['person'] = gone.is_person(c.person_kind_samples)
            lost = np.concatenate((lost, rows))
        self.lost = lost[-c.max_hypotheses:]

    def resume(self, hyp: Hypotheses, newly: np.ndarray, t: float) -> None:
        """The ``newly`` confirmed hypotheses near a recently lost track of their kind take
        its id."""
        c = self.config
        if c.resume_time <= 0 or not newly.size or not len(self.lost):
            return
        lost = self.lost[self.lost['stamp'] >= t - c.resume_time]
        if not len(lost):
            self.lost = lost
            return
        person = hyp.is_person(c.person_kind_samples)[newly]
        d = pairwise_distances(hyp.position[newly], lost['position'])
        d[person[:, None] != lost['person'][None, :]] = np.inf
        taken = np.zeros(len(lost), bool)
        done = np.zeros(len(newly), bool)
        ids = hyp.track_id
        for flat in np.argsort(d, axis=None):
            i, j = divmod(int(flat), len(lost))
            if d[i, j] > c.resume_radius:
                break
            if taken[j] or done[i]:
                continue
            taken[j] = done[i] = True
            ids[newly[i]] = lost['track_id'][j]
            self.stats['resumed'] += 1
        self.lost = lost[~taken]


def _squared_distances(xy: np.ndarray) -> np.ndarray:
    """(k, k) squared distances between the rows of ``xy`` (k, 2)."""
    x, y = xy[:, 0], xy[:, 1]
    dx, dy = x[:, None] - x[None, :], y[:, None] - y[None, :]
    dx *= dx
    dy *= dy
    dx += dy
    return dx


def _first_of_group(group: np.ndarray, order: np.ndarray) -> np.ndarray:
    """Mask: the first member of each group (labels ``group``) in ``order``."""
    k = group.size
    rank = np.empty(k, np.intp)
    rank[order] = np.arange(k)
    best = np.full(k, k, np.intp)
    np.minimum.at(best, group, rank)
    return rank == best[group]


def _components(k: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Connected components (label = smallest member index) of k nodes with edges a-b."""
    label = np.arange(k)
    while True:
        m = np.minimum(label[a], label[b])
        new = label.copy()
        np.minimum.at(new, a, m)
        np.minimum.at(new, b, m)
        new = new[new]
        if not np.count_nonzero(new != label):
            return label
        label = new
