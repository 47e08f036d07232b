"""What a stream of stamped messages may do, and how each stage answers it.

Real streams misbehave: a bag replayed in a loop sends time backwards, a second publisher on
a topic sends every message twice, a sensor pauses, odometry stops. Each stage of the
pipeline (``core.stages``) owns one :class:`StreamRules` and answers these cases itself, so
offline replay and the ROS nodes behave identically:

* **backwards** (a stamp before the previous one): the stage restarts (its history belongs
  to another pass through time);
* **duplicate** (the previous stamp again): the item is skipped;
* **gap** (more than ``max_gap`` seconds since the previous item): the stage forgets what a
  gap makes stale (each stage says what);
* **invalid** (a stamp that is not finite or is negative): the item is skipped.

Everything unusual is counted and logged through an :class:`EventLog`: the first occurrence
of a reason at once, then at the 10th, 100th, ... (no floods), and all counts for summaries.

A scanner faster than the method's scan counts were set for is thinned by
:class:`ScanThinning`.

Also here: :class:`OdometryWait` (a scan waits for the odometry that covers it, paper Sec. 3:
odometry arrives late and jittered), :class:`ClockOffset` (odometry stamped by another clock
than the scans) and :class:`StampPairer` (joins streams that carry the same stamps, e.g. a
scan and its pose).
"""
from __future__ import annotations

import logging
import math
import statistics
from collections import Counter, OrderedDict, deque
from collections.abc import Callable, Iterable
from typing import Generic, TypeVar

T = TypeVar('T')

FIRST, NEXT, DUPLICATE, BACKWARDS, GAP, INVALID = (
    'first', 'next', 'duplicate', 'backwards', 'gap', 'invalid')
SKIPPED = (INVALID, DUPLICATE)     # verdicts whose item a stage drops


class EventLog:
    """Counts events by reason and logs them without flooding.

    ``note(reason, detail)`` logs ``'<reason>: <detail>'`` the first time a reason occurs and
    again at its 10th, 100th, 1000th ... occurrence (with the count); other occurrences go to
    the debug log. ``counts`` holds every reason's count (for summary.json).
    """

    def __init__(self, logger: logging.Logger, prefix: str = ''):
        self.logger = logger
        self.prefix = prefix
        self.counts: Counter = Counter()

    def note(self, reason: str, detail: str = '', level: int = logging.WARNING) -> None:
        self.counts[reason] += 1
        n = self.counts[reason]
        text = f'{self.prefix}{reason}' + (f': {detail}' if detail else '')
        if n == 1 or (n >= 10 and math.log10(n).is_integer()):
            self.logger.log(level, '%s%s', text, f' ({n} times so far)' if n > 1 else '')
        else:
            self.logger.debug('%s', text)

    def lines(self) -> list[str]:
        """One line per reason with its count (the end-of-run summary)."""
        return [f'{self.prefix}{reason}: {n}' for reason, n in sorted(self.counts.items())]


class StreamRules:
    """Classifies each stamp of one stream against the previous accepted one."""

    def __init__(self, max_gap: float = math.inf):
        self.max_gap = float(max_gap)
        self.last: float | None = None

    def reset(self) -> None:
        self.last = None

    def classify(self, stamp: float) -> str:
        """One of FIRST, NEXT, DUPLICATE, BACKWARDS, GAP, INVALID (does not accept it)."""
        if not math.isfinite(stamp) or stamp < 0.0:
            return INVALID
        if self.last is None:
            return FIRST
        if stamp == self.last:
            return DUPLICATE
        if stamp < self.last:
            return BACKWARDS
        if stamp - self.last > self.max_gap:
            return GAP
        return NEXT

    def screen(self, stamp: float, item: str, events: EventLog) -> str:
        """``classify(stamp)``; a verdict in SKIPPED is noted in ``events`` as '<item>
        skipped: ...' (the caller drops the item)."""
        verdict = self.classify(stamp)
        if verdict in SKIPPED:
            unset = ' (a header stamp of 0: its publisher never sets it)' if stamp == 0 else ''
            events.note(f'{item} skipped: {verdict} stamp', f't={stamp!r}{unset}')
        return verdict

    def accept(self, stamp: float) -> None:
        self.last = float(stamp)


class ScanThinning:
    """Which scans of a fast scanner a stage uses: about ``max_rate`` a second at most.

    The scanner's period T is the median of its last 15 intervals. A scanner faster than
    4/3 of ``max_rate`` (T below three quarters of 1 / ``max_rate``) has a scan used once
    1 / ``max_rate`` less T / 3 has passed since the one used last: at 10 Hz, every second
    scan of a 15 or 20 Hz scanner, every third at 25 or 30 Hz, every fourth at 40 Hz. A
    slower scanner, with whatever jitter its stamps have, uses every scan, and so does
    ``max_rate`` 0. Stamps come screened (:class:`StreamRules`): increasing."""

    def __init__(self, max_rate: float):
        self.max_rate = float(max_rate)
        self.reset()

    def reset(self) -> None:
        self.intervals: deque[float] = deque(maxlen=15)
        self.last: float | None = None       # the latest scan seen
        self.used: float | None = None       # the latest scan used

    @property
    def period(self) -> float | None:
        """The scanner's median period (s), once three intervals are known."""
        return statistics.median(self.intervals) if len(self.intervals) >= 3 else None

    def use(self, stamp: float) -> bool:
        """Whether the scan stamped ``stamp`` is used."""
        if self.last is not None and stamp > self.last:
            self.intervals.append(stamp - self.last)
        self.last = stamp
        if self.used is not None and self.max_rate > 0.0:
            period = self.period
            if period is not None and period < 0.75 / self.max_rate and \
                    stamp - self.used < 1.0 / self.max_rate - period / 3.0:
                return False
        self.used = stamp
        return True


class OdometryWait(Generic[T]):
    """Holds scans (in arrival order) until odometry stamped at or after them has arrived, so
    the odometry prior is interpolated rather than extrapolated.

    A scan waits at most ``max_wait`` seconds after its arrival. When a wait runs out the
    odometry stream counts as *stalled*: everything held is released at once and later scans
    pass without waiting until odometry arrives again. A stream that stops therefore costs
    ``max_wait`` once, not on every scan. Without odometry in the last ``max_wait`` seconds (a
    robot without odometry) scans never wait.
    """

    def __init__(self, max_wait: float):
        self.max_wait = float(max_wait)
        self._pending: deque[tuple[float, float, T]] = deque()   # (arrival, stamp, item)
        self._odometry_stamp = -math.inf
        self._odometry_arrival = -math.inf
        self._stalled = False
        self.stalls = 0

    def __len__(self) -> int:
        return len(self._pending)

    def add_scan(self, arrival: float, stamp: float, item: T) -> list[T]:
        """Queue a scan; return the items that are ready, oldest first."""
        ready = self.release(arrival)
        if not self._pending and (self._stalled or stamp <= self._odometry_stamp
                                  or arrival - self._odometry_arrival > self.max_wait):
            return ready + [item]
        self._pending.append((arrival, stamp, item))
        return ready + self.release(arrival)

    def add_odometry(self, arrival: float, stamp: float) -> list[T]:
        self._odometry_stamp = max(self._odometry_stamp, stamp)
        self._odometry_arrival = max(self._odometry_arrival, arrival)
        self._stalled = False
        return self.release(arrival)

    def forget_odometry(self) -> None:
        """The odometry's stamps so far are void (read on another clock): held scans wait for
        the next sample."""
        self._odometry_stamp = -math.inf

    def release(self, now: float) -> list[T]:
        """Items whose odometry has arrived or whose wait is over at time ``now``."""
        ready = []
        while self._pending:
            arrival, stamp, item = self._pending[0]
            if stamp <= self._odometry_stamp:
                ready.append(self._pending.popleft()[2])
            elif now - arrival > self.max_wait:
                self._stalled = True
                self.stalls += 1
                ready.extend(entry[2] for entry in self._pending)
                self._pending.clear()
            else:
                break
        return ready

    def flush(self) -> list[T]:
        """Every held item (end of a recording)."""
        items = [item for _, _, item in self._pending]
        self._pending.clear()
        return items


class ClockOffset:
    """How far the scans' clock is ahead of the odometry's, from when their messages arrive.

    Each stream's stamp minus its arrival time is that stream's clock against the receiving
    one (plus a transport delay of milliseconds). When the medians of the last ``window``
    messages of each stream differ by more than ``tolerance`` seconds, the stamps come from
    different clocks (a scanner stamping with its own time, another computer): no latency
    explains that, and without the difference no odometry sample would ever lie near a
    scan. :attr:`offset` is then that difference (add it to an odometry stamp), else 0. It
    needs ``window`` messages of each stream; it is recomputed on each message.
    """

    def __init__(self, tolerance: float, window: int = 5):
        self.tolerance = float(tolerance)
        self._scans: deque[float] = deque(maxlen=window)
        self._odometry: deque[float] = deque(maxlen=window)
        self.offset = 0.0

    def add_scan(self, stamp: float, arrival: float) -> bool:
        """Note a scan; True when the offset changed."""
        self._scans.append(stamp - arrival)
        return self._update()

    def add_odometry(self, stamp: float, arrival: float) -> bool:
        """Note an odometry sample (its own stamp); True when the offset changed."""
        self._odometry.append(stamp - arrival)
        return self._update()

    def _update(self) -> bool:
        if len(self._scans) < self._scans.maxlen or \
                len(self._odometry) < self._odometry.maxlen:
            return False
        difference = statistics.median(self._scans) - statistics.median(self._odometry)
        offset = difference if abs(difference) > self.tolerance else 0.0
        changed = abs(offset - self.offset) > self.tolerance
        if changed or (offset == 0.0) != (self.offset == 0.0):
            self.offset = offset
            return True
        return False


class StampPairer:
    """Joins several streams whose messages carry identical stamps (an exact-time
    synchroniser): when every stream has delivered an item for one stamp key,
    ``on_complete({stream: item})`` is called.

    Keys are exact (integer nanoseconds of the header stamp: a float cannot hold an epoch
    stamp exactly). At most ``depth`` incomplete keys are kept, the oldest dropped first, and
    a completed key drops every older incomplete one (they can no longer complete in order).
    """

    def __init__(self, streams: Iterable[str], on_complete: Callable[[dict], None],
                 depth: int = 20):
        self.streams = tuple(streams)
        self.on_complete = on_complete
        self.depth = depth
        self.pending: OrderedDict[int, dict] = OrderedDict()
        self.dropped = 0

    def add(self, stream: str, key: int, item) -> None:
        if stream not in self.streams:
            raise ValueError(f'unknown stream {stream!r}; streams: {", ".join(self.streams)}')
        entry = self.pending.get(key)
        if entry is None:
            newest = next(reversed(self.pending), None)
            entry = self.pending[key] = {}
            if newest is not None and key < newest:   # keep keys in stamp order
                self.pending = OrderedDict(sorted(self.pending.items()))
        entry[stream] = item
        if len(entry) == len(self.streams):
            for old in [k for k in self.pending if k < key]:
                del self.pending[old]
                self.dropped += 1
            del self.pending[key]
            self.on_complete(entry)
            return
        while len(self.pending) > self.depth:
            self.pending.popitem(last=False)
            self.dropped += 1
