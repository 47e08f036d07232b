"""Deletion (paper Sec. 8): a hypothesis whose weight falls below ``remove_below`` is
removed; at most ``max_hypotheses`` live at once (the strongest are kept: confirmed first,
then by weight, then by samples; a warning when the bound is first hit, later hits are
counted until it clears)."""
from __future__ import annotations

import logging

import numpy as np

from laser_tracker.core.tracking.role import Role
from laser_tracker.core.tracking.state import Hypotheses

log = logging.getLogger('laser_tracker.core.hypotheses')   # the tracker's one log, all roles


class Deletion(Role):
    """Removal and the bound (see the module docstring)."""

    def __init__(self, config, filter, stats: dict):
        super().__init__(config, filter, stats)
        self.bound_active = False

    def delete(self, hyp: Hypotheses, t: float) -> tuple[Hypotheses, Hypotheses | None, bool]:
        """(the hypotheses kept, those removed by their weight or None when none was, whether
        the bound was hit)."""
        c = self.config
        keep = hyp.weight >= c.remove_below
        gone = None
        if np.count_nonzero(keep) < keep.size:
            hyp, gone = hyp.take(keep), hyp.take(~keep)
        bounded = len(hyp) > c.max_hypotheses
        if bounded:
            order = np.lexsort((-hyp.samples, -hyp.weight, ~hyp.confirmed))
            self.stats['bound_hits'] += 1
            if not self.bound_active:
                log.warning('t=%.3f: %d hypotheses exceed max_hypotheses=%d: the %d strongest '
                            'are kept (further hits are counted, not logged, until it clears)',
                            t, len(hyp), c.max_hypotheses, c.max_hypotheses)
            hyp = hyp.take(np.sort(order[:c.max_hypotheses]))
        self.bound_active = bounded
        return hyp, gone, bounded
