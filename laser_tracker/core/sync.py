"""Scans wait for their odometry (paper Sec. 3: odometry arrives late and jittered).

A scan is held, in arrival order, until odometry stamped at or after it has arrived (so the
ego-motion estimator can interpolate instead of extrapolating), or until ``max_wait`` seconds
have passed since it arrived. Without odometry in the last ``max_wait`` seconds (a scanner
with no odometry, or odometry that stopped) scans are not held at all. Used by offline replay
(arrival = the bag's receive time) and by the ``ego_motion`` node (arrival = the node's
clock), so both see the same order.
"""
from __future__ import annotations

from collections import deque
from typing import Generic, TypeVar

T = TypeVar('T')


class OdometryWait(Generic[T]):
    """Holds items stamped ``stamp`` (scans) until odometry covers them or they time out."""

    def __init__(self, max_wait: float):
        self.max_wait = float(max_wait)
        self._pending: deque[tuple[float, float, T]] = deque()   # (arrival, stamp, item)
        self._odometry_stamp = float('-inf')
        self._odometry_arrival = float('-inf')

    def __len__(self) -> int:
        return len(self._pending)

    def add_scan(self, arrival: float, stamp: float, item: T) -> list[T]:
        """Queue a scan; return the items that are ready, oldest first."""
        ready = self.release(arrival)
        if arrival - self._odometry_arrival > self.max_wait and not self._pending:
            return ready + [item]           # no odometry stream to wait for
        self._pending.append((arrival, stamp, item))
        return ready + self.release(arrival)

    def add_odometry(self, arrival: float, stamp: float) -> list[T]:
        self._odometry_stamp = max(self._odometry_stamp, stamp)
        self._odometry_arrival = max(self._odometry_arrival, arrival)
        return self.release(arrival)

    def release(self, now: float) -> list[T]:
        """Items whose odometry has arrived or whose wait is over at time ``now``."""
        ready = []
        while self._pending:
            arrival, stamp, item = self._pending[0]
            if stamp <= self._odometry_stamp or now - arrival > self.max_wait:
                self._pending.popleft()
                ready.append(item)
            else:
                break
        return ready

    def flush(self) -> list[T]:
        """Every held item (end of a recording)."""
        items = [item for _, _, item in self._pending]
        self._pending.clear()
        return items
