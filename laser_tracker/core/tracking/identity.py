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
  ``resume_radius`` of that track's way since (from where a blob, a person detection or a
  segment last measured it, on along its velocity then for the time since: it walked on or
  stopped somewhere on the way), takes its id (nearest pairs first, each lost track once):
  a target lost for a moment keeps its identity.
* **Take over** (``resume_confirms``): a person's hypothesis not confirmed yet, measured now,
  within ``resume_radius`` of the way of a confirmed person's track lost within
  ``resume_time`` continues it: the confirmation rules that ask for evidence of a walking
  person (``walked``, ``not_riding_along``) do not hold it back. A person's track pulled
  off them for a scan (a blob beside their legs while the robot turns), or faded while the
  detector missed them, leaves them to a new hypothesis; the evidence that they are a
  person was already gathered, and a person standing in view would otherwise wait to walk
  again.
"""
from __future__ import annotations

import numpy as np

from laser_tracker.core import jit
from laser_tracker.core.blobs import _root
from laser_tracker.core.tracking.role import Role
from laser_tracker.core.tracking.state import MOTION, PERSON, Hypotheses

#: A confirmed track lost recently (``resume_time``): its id, when it was lost, when and where
#: it was last measured, its velocity then, and whether it was a person.
LOST = np.dtype([('track_id', np.int64), ('stamp', np.float64), ('t_seen', np.float64),
                 ('seen', np.float64, (2,)), ('velocity', np.float64, (2,)),
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
        if len(hyp) < 2 or c.merge_distance <= 0:
            return hyp
        rows = hyp.rows
        groups = _duplicates(rows['position'], rows['state'], rows['supported'],
                             rows['weight'], rows['samples'], rows['track_id'],
                             rows['confirmed'], rows['origin'], c.merge_distance ** 2,
                             c.merge_speed ** 2)
        if groups is None:
            return hyp
        kept, src, samples, origin = groups
        out = hyp.take(kept)
        merged = out.rows
        for name in ('track_id', 'born', 'start', 'start_local'):
            merged[name] = rows[name][src]
        merged['confirmed'] |= rows['confirmed'][src]
        merged['samples'] = samples
        merged['origin'] = origin
        self.stats['merged'] += len(hyp) - kept.size
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
            rows['track_id'], rows['stamp'] = gone.track_id, t
            rows['t_seen'], rows['seen'] = gone.t_state, gone.state[:, :2]
            rows['velocity'] = gone.velocity
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
        d = _distances_to_lost(hyp.position[newly], lost, t)
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

    def continuing(self, hyp: Hypotheses, t: float) -> np.ndarray | None:
        """Mask over ``hyp``: the person hypotheses not confirmed yet, measured now, that take
        over a confirmed person's track lost within ``resume_time`` (module docstring); None
        when there is none (or ``resume_confirms`` is off)."""
        c = self.config
        if not c.resume_confirms or c.resume_time <= 0 or not len(hyp):
            return None
        lost = self.lost[(self.lost['stamp'] >= t - c.resume_time) & self.lost['person']]
        rows = (~hyp.confirmed & hyp.supported
                & hyp.is_person(c.person_kind_samples)).nonzero()[0]
        if not len(lost) or not rows.size:
            return None
        d = _distances_to_lost(hyp.position[rows], lost, t)
        mask = np.zeros(len(hyp), bool)
        mask[rows] = (d <= c.resume_radius).any(axis=1)
        return mask if mask.any() else None


def _distances_to_lost(xy: np.ndarray, lost: np.ndarray, t: float) -> np.ndarray:
    """(n, k): from each of ``xy`` (n, 2) to the way of each ``lost`` track (rows of
    ``LOST``) by ``t``: the segment from where it was last measured along its velocity then
    for the time since."""
    start = lost['seen']
    way = lost['velocity'] * (t - lost['t_seen'])[:, None]
    rel = xy[:, None, :] - start[None, :, :]
    length2 = (way ** 2).sum(axis=1)
    f = np.clip((rel * way[None]).sum(axis=2) / np.maximum(length2, 1e-12)[None], 0.0, 1.0)
    return np.hypot(*(rel - f[..., None] * way[None]).transpose(2, 0, 1))


@jit.kernel
def _duplicates(position, state, supported, weight, samples, track_id, confirmed, origin,
                near2, alike2):
    """The groups of duplicates (chains of hypotheses within ``sqrt(near2)`` of each other
    whose velocities, ``state[:, 2:]``, differ by at most ``sqrt(alike2)``), or None when
    there is nothing to merge. Per group: the row kept (its best-supported member: supported
    now, then weight, then samples, then the first), the row whose identity it takes (its
    oldest confirmed member, else its oldest: smallest id), the most samples of a member,
    and its origin (``MOTION`` unless every member was started by a person standing where
    something always stood)."""
    k = position.shape[0]
    root = np.arange(k)
    close = 0
    alike = 0
    for a in range(k):
        for b in range(k):
            dx, dy = position[a, 0] - position[b, 0], position[a, 1] - position[b, 1]
            if dx * dx + dy * dy <= near2:
                close += 1
                vx, vy = state[a, 2] - state[b, 2], state[a, 3] - state[b, 3]
                if vx * vx + vy * vy <= alike2:
                    alike += 1
                    if a < b:                    # join the groups: the smallest row is root
                        ra, rb = _root(root, a), _root(root, b)
                        root[max(ra, rb)] = min(ra, rb)
    if close == k or alike == k:                 # only the diagonal: nothing to merge
        return None
    best = np.full(k, -1)
    donor = np.full(k, -1)
    most = np.zeros(k, np.int64)
    open_ = np.zeros(k, np.bool_)
    for i in range(k):
        g = _root(root, i)
        j = best[g]
        if j < 0 or _better_state(i, j, supported, weight, samples):
            best[g] = i
        j = donor[g]
        if j < 0 or (confirmed[i] and not confirmed[j]) or (
                confirmed[i] == confirmed[j] and track_id[i] < track_id[j]):
            donor[g] = i
        most[g] = max(most[g], samples[i])
        open_[g] |= origin[i] != PERSON
    n = 0
    for i in range(k):
        n += best[_root(root, i)] == i
    kept, src = np.empty(n, np.intp), np.empty(n, np.intp)
    kept_samples, kept_origin = np.empty(n, np.int64), np.empty(n, np.int8)
    n = 0
    for i in range(k):
        g = _root(root, i)
        if best[g] == i:
            kept[n], src[n], kept_samples[n] = i, donor[g], most[g]
            kept_origin[n] = MOTION if open_[g] else PERSON
            n += 1
    return kept, src, kept_samples, kept_origin


@jit.inline
def _better_state(i, j, supported, weight, samples):
    """Row ``i`` (after ``j``) has the better state: supported now, then the higher weight
    (NaN last), then more samples."""
    if supported[i] != supported[j]:
        return supported[i]
    wi, wj = weight[i], weight[j]
    if wi != wj and not (wi != wi and wj != wj):
        return wj != wj or wi > wj
    return samples[i] > samples[j]
