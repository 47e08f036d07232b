"""Scans wait for the odometry that covers them, but never for an absent odometry stream; a
fast scanner is thinned to the rate the method was made for."""
import numpy as np
import pytest

from laser_tracker.core.stream import ClockOffset, OdometryWait, ScanThinning


def test_scan_is_held_until_odometry_stamped_after_it_arrives():
    wait = OdometryWait(max_wait=1.0)
    assert wait.add_odometry(arrival=0.0, stamp=0.0) == []
    assert wait.add_scan(arrival=0.25, stamp=0.2, item='s1') == []     # odometry only up to 0.0
    assert wait.add_scan(arrival=0.45, stamp=0.4, item='s2') == []
    assert wait.add_odometry(arrival=0.5, stamp=0.3) == ['s1']           # covers s1, not s2
    assert wait.add_odometry(arrival=0.6, stamp=0.45) == ['s2']
    assert len(wait) == 0


def test_scan_is_released_when_its_wait_is_over():
    wait = OdometryWait(max_wait=1.0)
    wait.add_odometry(0.0, 0.0)
    assert wait.add_scan(0.5, 0.4, 'late') == []
    assert wait.release(1.4) == []
    assert wait.release(1.6) == ['late']


def test_order_is_kept_and_flush_returns_the_rest():
    wait = OdometryWait(max_wait=1.0)
    wait.add_odometry(0.0, 0.0)
    wait.add_scan(0.1, 0.1, 'a')
    wait.add_scan(0.2, 0.2, 'b')
    assert wait.add_odometry(0.3, 0.25) == ['a', 'b']
    wait.add_scan(0.4, 0.4, 'c')
    assert wait.flush() == ['c']


def test_without_odometry_scans_pass_at_once():
    wait = OdometryWait(max_wait=1.0)
    assert wait.add_scan(0.0, 0.0, 'a') == ['a']
    assert wait.add_scan(0.2, 0.2, 'b') == ['b']
    wait.add_odometry(0.3, 0.3)
    assert wait.add_scan(0.4, 0.4, 'c') == []       # odometry flowing again: wait for it
    assert wait.release(2.0) == ['c']
    assert wait.add_scan(2.5, 2.5, 'd') == ['d']    # odometry stopped 2.2 s ago


def _feed(clocks, n, scan_ahead, start=0):
    """``n`` scans at 10 Hz and odometry at 50 Hz arriving 10 ms after their stamps, the
    scans stamped ``scan_ahead`` s ahead of the odometry's clock; the changes reported."""
    changes = []
    for k in range(start, start + n):
        t = 0.1 * k
        for j in range(5):
            changes.append(clocks.add_odometry(t + 0.02 * j, t + 0.02 * j + 0.01))
        changes.append(clocks.add_scan(t + scan_ahead, t + 0.015))
    return sum(changes)


@pytest.mark.parametrize('scan_ahead, offset', [(0.0, 0.0), (1.5, 0.0), (130.0, 130.0),
                                                (-42.0, -42.0)])
def test_a_clock_offset_is_found_from_arrivals_beyond_any_latency(scan_ahead, offset):
    """Stamps that differ from the arrival of the other stream's by more than the tolerance
    (2 s) are of another clock: the offset, to within the transport delays; less is a
    latency (``odom_latency``), left alone."""
    clocks = ClockOffset(2.0, window=5)
    assert _feed(clocks, 3, scan_ahead) == 0 and clocks.offset == 0.0   # too few scans yet
    changes = _feed(clocks, 20, scan_ahead, start=3)
    assert clocks.offset == pytest.approx(offset, abs=0.01)
    assert changes == (1 if offset else 0)                      # said once


def test_a_clock_offset_that_goes_away_is_dropped():
    clocks = ClockOffset(2.0, window=5)
    _feed(clocks, 10, 60.0)
    assert clocks.offset == pytest.approx(60.0, abs=0.01)
    assert _feed(clocks, 10, 0.0, start=10) == 1 and clocks.offset == 0.0


def _used(rate_hz: float, max_rate: float, seconds: float = 4.0, jitter: float = 0.0,
          seed: int = 0) -> list[float]:
    """The stamps a ScanThinning at ``max_rate`` uses of a scanner at ``rate_hz``, whose
    stamps jitter by up to ``jitter`` of its period."""
    thinning = ScanThinning(max_rate)
    rng = np.random.default_rng(seed)
    n = int(seconds * rate_hz)
    stamps = np.arange(n) / rate_hz + rng.uniform(-jitter, jitter, n) / rate_hz
    return [t for t in stamps if thinning.use(float(t))]


@pytest.mark.parametrize('rate_hz, every', [(15.0, 2), (20.0, 2), (25.0, 3), (30.0, 3),
                                            (40.0, 4), (50.0, 5)])
def test_a_fast_scanner_is_thinned_to_about_ten_scans_a_second(rate_hz, every):
    used = _used(rate_hz, 10.0)
    steps = np.round(np.diff(used[3:]) * rate_hz).astype(int)   # after its period is known
    assert set(steps.tolist()) == {every}
    assert 7.0 <= 1.0 / np.median(np.diff(used[3:])) <= 10.0 + 1e-9


@pytest.mark.parametrize('rate_hz, jitter', [(4.3, 0.3), (5.0, 0.3), (7.5, 0.3), (10.0, 0.3),
                                             (12.0, 0.1)])
def test_a_scanner_up_to_four_thirds_of_the_rate_keeps_every_scan_despite_jitter(rate_hz,
                                                                                  jitter):
    n = int(4.0 * rate_hz)
    assert len(_used(rate_hz, 10.0, jitter=jitter)) == n


def test_thinning_off_and_after_a_reset_every_scan_counts():
    assert len(_used(40.0, 0.0)) == 160
    thinning = ScanThinning(10.0)
    assert [k for k in range(12) if thinning.use(k / 40.0)] == [0, 1, 2, 6, 10]
    thinning.reset()                  # a restart: the next scan is used, the period relearnt
    assert thinning.use(12 / 40.0) and thinning.period is None
    # a scanner that drops scans: the first one after the gap is used at once
    thinning = ScanThinning(10.0)
    used = [t for t in [k / 40.0 for k in range(16)] + [0.6] if thinning.use(t)]
    assert used[-1] == 0.6 and used[-2] <= 0.375
