"""The detection message (``core.detections.Detections``) across the ``blobs`` topic: every
field of motion blobs, people, segments and the view comes back as it went, for rclpy and rosbags
messages alike; a MarkerArray that is not a blobs message is refused."""
from __future__ import annotations

import math

import numpy as np
import pytest

from laser_tracker.conversions import (bag_factory, detections_from_marker_array,
                                       detections_to_marker_array, ros_factory)
from laser_tracker.core.detections import Blobs, Detections, People, Segments, View
from laser_tracker.tools.bag import TYPESTORE


def message() -> Detections:
    return Detections(
        stamp=12.5, origin=np.array([1.0, -2.0, 0.75]), frame_id='odom', restarted=True,
        stamp_ns=12_500_000_000,
        blobs=Blobs(xy=np.array([[1.5, 0.25], [-3.0, 4.0]]), cells=np.array([3, 11]),
                    extent=np.array([0.2, 0.6]), structure=np.array([np.nan, 1.25])),
        people=People(xy=np.array([[2.0, 1.0], [0.5, -0.5]]), confidence=np.array([0.9, 0.45]),
                      free=np.array([True, False]), spread=np.array([0.3, np.nan]),
                      static=np.array([False, True])),
        segments=Segments(xy=np.array([[1.0, 1.0], [2.0, 3.0], [4.0, 0.0]]),
                          leg=np.array([0.8, 0.01, 0.0]),
                          occupied=np.array([0.0, 2.5, 10.0])),
        view=View(bearing=np.array([-2.0, -0.5, 0.0, 1.0, 2.5]),
                  reach=np.array([0.3, np.inf, 4.25, -np.inf, 11.0]),
                  background=np.array([False, False, True, False, True])))


@pytest.mark.parametrize('factory', [ros_factory(), bag_factory(TYPESTORE)],
                         ids=['rclpy', 'rosbags'])
def test_every_field_crosses_the_blobs_topic(factory):
    sent = message()
    got = detections_from_marker_array(detections_to_marker_array(factory, sent))
    assert (got.stamp, got.frame_id, got.restarted, got.stamp_ns) == \
        (sent.stamp, sent.frame_id, sent.restarted, sent.stamp_ns)
    np.testing.assert_allclose(got.origin, sent.origin, atol=1e-12)
    b, s = got.blobs, sent.blobs
    np.testing.assert_array_equal(b.xy, s.xy)
    assert b.cells.tolist() == s.cells.tolist() and b.count == 2
    np.testing.assert_allclose(b.extent, s.extent)
    assert math.isnan(b.structure[0]) and b.structure[1] == s.structure[1]
    p, q = got.people, sent.people
    np.testing.assert_array_equal(p.xy, q.xy)
    np.testing.assert_allclose(p.confidence, q.confidence)
    assert p.free.tolist() == q.free.tolist() and p.static.tolist() == q.static.tolist()
    assert p.spread[0] == pytest.approx(0.3) and math.isnan(p.spread[1])
    np.testing.assert_array_equal(got.segments.xy, sent.segments.xy)
    np.testing.assert_allclose(got.segments.leg, sent.segments.leg)
    np.testing.assert_allclose(got.segments.occupied, sent.segments.occupied)
    np.testing.assert_allclose(got.view.bearing, sent.view.bearing, atol=1e-9)
    np.testing.assert_allclose(got.view.reach, sent.view.reach, atol=1e-9)
    assert got.view.background.tolist() == sent.view.background.tolist()


def test_an_empty_scan_is_an_empty_message():
    got = detections_from_marker_array(detections_to_marker_array(
        ros_factory(), Detections(stamp=3.0, origin=np.zeros(3))))
    assert got.blobs.count == 0 and len(got.people) == 0 and len(got.segments) == 0
    assert len(got.view) == 0
    assert got.stamp == 3.0 and not got.restarted


@pytest.mark.parametrize('text', [
    '{"leg":[0.8,0.01,0.0]}', '{"leg":[0.8,0.01,0.0],"occupied":[1.0]}',
    '{"leg":[0.8,0.01,0.0],"occupied":"long"}', '[1, 2]', 'not json'])
def test_segments_without_a_readable_occupancy_decode_as_not_known(text):
    """An older message (no occupancy), or one whose occupancy is not one number per
    segment, decodes to an unknown occupancy; the leg probabilities still come through
    where they are readable, and no segment is lost."""
    msg = detections_to_marker_array(ros_factory(), message())
    (seg,) = [m for m in msg.markers if m.ns == 'segments']
    seg.text = text
    got = detections_from_marker_array(msg).segments
    assert len(got) == 3 and got.occupied.size == 0
    readable = text.startswith('{"leg"')
    assert got.leg.tolist() == ([0.8, 0.01, 0.0] if readable else [0.0, 0.0, 0.0])


def test_a_marker_array_without_the_scanner_is_not_a_blobs_message():
    msg = detections_to_marker_array(ros_factory(), message())
    msg.markers = [m for m in msg.markers if m.ns != 'scanner']
    with pytest.raises(ValueError, match='not a blobs message'):
        detections_from_marker_array(msg)


def test_the_view_of_a_scan_tells_returns_silence_and_too_close_apart():
    """REP 117: a return within range is its range; +inf, NaN, a code below range_min and a
    reading at range_max returned nothing (+inf); -inf was too close to measure."""
    from laser_tracker.core.scan import Scan
    scan = Scan(stamp=1.0, ranges=np.array([2.5, np.inf, np.nan, 0.01, 30.0, -np.inf]),
                angle_min=-0.5, angle_increment=0.2, range_min=0.05, range_max=30.0)
    view = View.of_scan(scan)
    assert view.reach.tolist() == [2.5, np.inf, np.inf, np.inf, np.inf, -np.inf]
    np.testing.assert_allclose(view.bearing, -0.5 + 0.2 * np.arange(6))
