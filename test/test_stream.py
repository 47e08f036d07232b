"""Scans wait for the odometry that covers them, but never for an absent odometry stream."""
from laser_tracker.core.stream import OdometryWait


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
