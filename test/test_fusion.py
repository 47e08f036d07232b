"""People by leg shape fused with what moves, through the detection stage and the nodes' messages:
a person who walks in is tracked and may then stand; legs where something always stood
(table legs) are not a confirmed person; a missing model leaves the motion method running."""
from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np

from laser_tracker.core.difference import PoseQuality
from laser_tracker.core.person_detector import PersonDetectorConfig
from laser_tracker.core.pipeline import Pipeline, PipelineConfig
from laser_tracker.core.stages import Detector, StampedPose
from leg_scenes import box, scene

DT = 0.1
WALLS = [(-1, 4, 8, 4), (8, 4, 8, -4), (8, -4, -1, -4)]


def pose(t):
    return StampedPose(stamp=t, pose=np.zeros(3), motion=np.zeros(3),
                       motion_covariance=np.zeros((3, 3)), pose_covariance=np.zeros((3, 3)),
                       quality=PoseQuality())


def legs(x, y, k):
    """Two legs of a person at (x, y) walking along y: they swing (their separation
    varies with the step ``k`` between 0.25 and 0.45 m)."""
    s = 0.25 + 0.2 * abs(math.sin(k * 0.6))
    return [(x, y - s / 2, 0.06), (x, y + s / 2, 0.06)]


def stamped_scan(t, circles, walls=WALLS):
    s = scene(circles, walls)
    s.stamp = t
    return s


# The synthetic legs are clean circles; the shipped model, trained on real scans, gives
# them about 0.6: these tests of the fusion take 0.5 as the leg threshold.
CONFIG = PipelineConfig().replace(person_detector={'threshold': 0.5})


def run(scans):
    pipeline = Pipeline(CONFIG)
    return [pipeline.step(s) for s in scans], pipeline


def test_a_person_who_walks_in_then_stands_is_one_person_track():
    scans = []
    for k in range(60):
        t = 1.0 + k * DT
        y = -2.5 + min(k, 30) * 0.1            # walks 3 m, then stands for 3 s
        step = k if k < 30 else 30
        scans.append(stamped_scan(t, legs(3.0, y, step)))
    results, pipeline = run(scans)
    ids = set()
    for r in results[10:]:
        h = r.hypotheses
        ids |= set(h.track_id[h.confirmed].tolist())
    assert len(ids) == 1, ids
    tracks = pipeline.tracker.tracks()
    (i,) = np.flatnonzero(tracks.confirmed)
    assert tracks.kind[i] == 'person' and not tracks.moving[i]
    assert np.allclose(tracks.position[i], (3.0, 0.5), atol=0.25)


def test_table_legs_in_view_all_along_are_not_a_person():
    table = [(2.5, -0.4, 0.05), (2.5, 0.4, 0.05), (3.1, -0.4, 0.05), (3.1, 0.4, 0.05)]
    scans = [stamped_scan(1.0 + k * DT, table) for k in range(60)]
    results, pipeline = run(scans)
    detected = sum(len(r.detections.people) for r in results)
    confirmed = {int(i) for r in results for i in r.hypotheses.track_id[r.hypotheses.confirmed]}
    assert detected > 0, 'the table legs should look like legs to the detector'
    assert not confirmed


def test_person_detections_cross_the_blobs_message_unchanged():
    from laser_tracker.conversions import (bag_factory, detections_from_marker_array,
                                           detections_to_marker_array, ros_factory)
    from laser_tracker.tools.bag import TYPESTORE

    det = Detector(CONFIG.grid, CONFIG.difference, CONFIG.blobs, CONFIG.person_detector)
    for k in range(12):
        out = det.update(stamped_scan(1.0 + k * DT, legs(3.0, -1.0 + 0.1 * k, k)),
                         pose(1.0 + k * DT))
    people, segments = out.detections.people, out.detections.segments
    assert len(people) >= 1 and len(segments) >= 2
    for factory in (ros_factory(), bag_factory(TYPESTORE)):
        back = detections_from_marker_array(detections_to_marker_array(factory,
                                                                      out.detections))
        np.testing.assert_allclose(back.people.xy, people.xy)
        np.testing.assert_allclose(back.people.confidence, people.confidence, atol=1e-4)
        assert back.people.free.tolist() == people.free.tolist()
        assert back.people.static.tolist() == people.static.tolist()
        np.testing.assert_allclose(back.people.spread, people.spread, atol=1e-4)
        np.testing.assert_allclose(back.segments.xy, segments.xy)
        np.testing.assert_allclose(back.segments.leg, segments.leg, atol=1e-3)


def test_a_missing_model_leaves_the_motion_method_running(tmp_path, caplog):
    config = PipelineConfig().replace(person_detector={'model': str(tmp_path / 'none.npz')})
    with caplog.at_level(logging.WARNING):
        pipeline = Pipeline(config)
    assert pipeline.detector.person_detector is None
    assert 'none.npz' in caplog.text and 'motion method' in caplog.text
    scans = [stamped_scan(1.0 + k * DT, [(3.0, -2.0 + 0.15 * k, 0.12)]) for k in range(15)]
    results = [pipeline.step(s) for s in scans]
    assert any(r.hypotheses.confirmed.any() for r in results)
    assert all(len(r.detections.people) == 0 for r in results)


def test_the_detector_can_be_switched_off_and_is_off_in_the_paper_reference():
    from pathlib import Path

    from laser_tracker import parameters
    off = PipelineConfig().replace(person_detector={'enabled': False})
    assert Pipeline(off).detector.person_detector is None
    paper = parameters.pipeline_config(parameters.load_files(
        [Path(__file__).resolve().parents[1] / 'config' / 'paper_reference.yaml']))
    assert paper.person_detector.enabled is False
    assert dataclasses.replace(paper.person_detector, enabled=True) == \
        dataclasses.replace(PersonDetectorConfig(), enabled=True)


def test_a_box_wall_is_no_person():
    scans = [stamped_scan(1.0 + k * DT, [], WALLS + box(3.0, 0.0, 0.8)) for k in range(20)]
    results, _ = run(scans)
    assert all(len(r.detections.people) == 0 for r in results)
