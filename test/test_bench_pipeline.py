"""bench pipeline's recordings: a name the user gives is read or refused, never replaced."""
from __future__ import annotations

import pytest

from laser_tracker.errors import LaserTrackerError
from laser_tracker.tools.bench_pipeline import sources


def test_a_named_recording_that_does_not_exist_is_an_error_not_synthetic_scans():
    with pytest.raises(LaserTrackerError, match='neither a readable recording'):
        sources(['exp1_stationary_single_walker,hokuyo_corridor_lobby'])


def test_a_bundled_recording_is_read_by_its_name():
    (events,) = sources(['exp1_stationary_single_walker'])
    assert events.name == 'exp1_stationary_single_walker'
    assert events.n_scans > 100


def test_without_any_recording_the_defaults_fall_back_to_synthetic_scans():
    (events,) = sources(['no_such_recording'], named=False)
    assert events.n_scans > 0
