"""The person detector: numpy tree inference, the model file, legs paired into people."""
import dataclasses
import json
import zipfile

import numpy as np
import pytest
from leg_scenes import box, scene

from laser_tracker.config import ConfigError, from_dict
from laser_tracker.core.person_detector import (MODEL_VERSION, PACKAGED_MODEL,
                                                DetectorModelError, LegClassifier,
                                                PersonDetector, PersonDetectorConfig,
                                                load_model, save_model)
from laser_tracker.core.grid import GridConfig
from laser_tracker.core.scan import Scan
from laser_tracker.core.segmentation import FEATURE_NAMES, FEATURE_SET
from laser_tracker.errors import LaserTrackerError
from laser_tracker.tools.data import real_recording

WIDTH = FEATURE_NAMES.index('width')


def width_classifier(threshold=0.5) -> LegClassifier:
    """One tree of depth 1: a cluster at most 0.2 m wide is a leg (p = 0.95), else not."""
    return LegClassifier(feature=np.array([[WIDTH]]), threshold=np.array([[0.2]]),
                         value=np.array([[3.0, -3.0]]), bias=-0.0555,
                         meta={'threshold': threshold})


P_LEG = 1 / (1 + np.exp(-(3.0 - 0.0555)))


# ------------------------------------------------------------------ inference = sklearn

def _fitted(depth, seed=0):
    sklearn = pytest.importorskip('sklearn.ensemble')
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(600, len(FEATURE_NAMES)))
    y = ((X[:, 0] + X[:, 3] ** 2 - X[:, 7] > 0.5) ^ (rng.random(600) < 0.1)).astype(int)
    model = sklearn.GradientBoostingClassifier(n_estimators=25, max_depth=depth,
                                               learning_rate=0.3, subsample=0.8,
                                               random_state=seed)
    model.fit(X, y, sample_weight=np.where(y == 1, 2.0, 1.0))
    return model, X


@pytest.mark.parametrize('depth', [1, 2, 3, 4])
def test_inference_equals_sklearn(depth):
    from laser_tracker.tools.train_detector import export

    model, X = _fitted(depth)
    clf = export(model, {'threshold': 0.5})
    assert clf.depth == max(e[0].tree_.max_depth for e in model.estimators_)
    # rows exactly at split thresholds (as float32) test the <= / > convention
    used = clf.feature[clf.threshold < np.inf]
    thr = clf.threshold[clf.threshold < np.inf]
    edge = X[:used.size].copy()
    edge[np.arange(used.size), used] = thr.astype(np.float32)
    for rows in (X, edge, X[:1], np.zeros((0, len(FEATURE_NAMES)))):
        np.testing.assert_allclose(clf.predict_proba(rows),
                                   model.predict_proba(rows)[:, 1] if len(rows) else [],
                                   rtol=0, atol=1e-12)


def test_scores_equal_walking_the_trees_in_numpy_bit_for_bit():
    """The kernel's raw scores are those of the trees walked with numpy, the leaves summed
    as numpy sums a row (what the figures measured with numpy inference rest on)."""
    clf = load_model()
    X = np.random.default_rng(1).normal(size=(300, len(FEATURE_NAMES))) * 3
    X[:5] = 0.0
    x = X.astype(np.float32).astype(np.float64)
    trees, inner = clf.feature.shape
    node = np.zeros((X.shape[0], trees), np.intp)
    for _ in range(clf.depth):
        feature = clf.feature[np.arange(trees), node]
        right = x[np.arange(X.shape[0])[:, None], feature] > clf.threshold[np.arange(trees), node]
        node = 2 * node + 1 + right
    leaves = clf.value[np.arange(trees), node - inner]
    np.testing.assert_array_equal(clf.decision_function(X), clf.bias + leaves.sum(axis=1))


# ------------------------------------------------------------------------ model files

def test_packaged_model_is_small_and_current():
    assert PACKAGED_MODEL.is_file()
    assert PACKAGED_MODEL.stat().st_size < 1024 * 1024
    clf = load_model('')
    assert clf.meta['feature_set'] == FEATURE_SET
    assert clf.meta['feature_names'] == list(FEATURE_NAMES)
    assert 0.0 < clf.recommended_threshold < 1.0
    p = clf.predict_proba(np.random.default_rng(0).normal(size=(20, len(FEATURE_NAMES))))
    assert ((p >= 0) & (p <= 1)).all()


def test_setup_cfg_ships_the_model():
    import configparser
    from pathlib import Path

    cfg = configparser.ConfigParser()
    cfg.read(Path(__file__).resolve().parents[1] / 'setup.cfg')
    assert 'models/*.npz' in cfg['options.package_data']['laser_tracker']


def test_save_and_load_round_trip(tmp_path):
    clf = load_model()
    path = tmp_path / 'copy.npz'
    save_model(path, clf)
    again = load_model(path)
    X = np.random.default_rng(2).normal(size=(50, len(FEATURE_NAMES)))
    np.testing.assert_array_equal(again.predict_proba(X), clf.predict_proba(X))
    assert again.recommended_threshold == clf.recommended_threshold


def _rewrite(src, dest, **changes):
    with np.load(src) as data:
        arrays = {k: data[k] for k in data.files}
    header = json.loads(str(arrays['header']))
    header.update(changes.pop('header', {}))
    arrays['header'] = np.array(json.dumps(header))
    arrays.update(changes)
    np.savez(dest, **arrays)


def _bad_files(tmp_path):
    good = PACKAGED_MODEL.read_bytes()
    files = {}
    files['missing'] = tmp_path / 'missing.npz'
    files['truncated'] = tmp_path / 'truncated.npz'
    files['truncated'].write_bytes(good[:len(good) // 2])
    files['garbage'] = tmp_path / 'garbage.npz'
    files['garbage'].write_bytes(np.random.default_rng(0).bytes(4000))
    files['text'] = tmp_path / 'model.yaml'
    files['text'].write_text('trees: 50\n')
    files['empty'] = tmp_path / 'empty.npz'
    files['empty'].write_bytes(b'')
    files['folder'] = tmp_path
    files['other_zip'] = tmp_path / 'other.npz'
    with zipfile.ZipFile(files['other_zip'], 'w') as z:
        z.writestr('readme.txt', 'not a model')
    for name, change in {
            'old_version': {'header': {'version': MODEL_VERSION + 1}},
            'other_format': {'header': {'format': 'something.else'}},
            'other_features': {'header': {'feature_set': 'leg-shape-0',
                                          'feature_names': ['n_points', 'width']}},
            'bad_index': {'feature': np.full((3, 7), 99, dtype=np.int16),
                          'threshold': np.zeros((3, 7)), 'value': np.zeros((3, 8))},
            'not_a_tree': {'value': np.zeros((50, 5))},
            'nan_values': {'value': np.full((50, 8), np.nan)}}.items():
        files[name] = tmp_path / f'{name}.npz'
        _rewrite(PACKAGED_MODEL, files[name], **change)
    return files


def test_unusable_model_files_raise_a_clear_error(tmp_path):
    for name, path in _bad_files(tmp_path).items():
        with pytest.raises(DetectorModelError) as info:
            load_model(path)
        message = str(info.value)
        assert str(path) in message, name
        assert '\n' not in message, name
        assert isinstance(info.value, LaserTrackerError)
    with pytest.raises(DetectorModelError, match='retrain'):
        load_model(tmp_path / 'other_features.npz')
    with pytest.raises(DetectorModelError, match='version'):
        load_model(tmp_path / 'old_version.npz')


def test_detector_with_a_bad_model_file_fails_at_construction(tmp_path):
    config = PersonDetectorConfig(model=str(tmp_path / 'none.npz'))
    with pytest.raises(DetectorModelError, match='none.npz'):
        PersonDetector(config)


# ------------------------------------------------------------------- people from legs

def test_the_pairing_kernel_computes_hypot_as_python_does():
    """The lone leg's distance is ``math.hypot`` as CPython computes it (not libm's hypot,
    which differs in the last bit now and then), so people stay where the list code put
    them."""
    import math

    from laser_tracker.core.jit import python_hypot
    rng = np.random.default_rng(4)
    xy = rng.normal(size=(20000, 2)) * 10.0 ** rng.uniform(-3, 2, size=(20000, 1))
    assert [python_hypot(x, y) for x, y in xy] == [math.hypot(x, y) for x, y in xy]
    assert python_hypot(0.0, 0.0) == 0.0 and python_hypot(-3.0, 4.0) == 5.0


def test_two_legs_make_one_person_at_their_midpoint():
    det = PersonDetector(PersonDetectorConfig(), width_classifier())
    out = det.detect(scene([(2.0, 0.15, 0.06), (2.0, -0.15, 0.06)]))
    assert out.count == 1
    legs = out.leg_xy[out.legs[0]]
    np.testing.assert_allclose(out.xy[0], legs.mean(axis=0))
    assert abs(out.xy[0, 1]) < 0.01 and 1.9 < out.xy[0, 0] < 2.0
    np.testing.assert_allclose(out.confidence, [P_LEG])
    assert out.is_leg.sum() == 2


def test_lone_legs_are_people_behind_the_leg_with_lower_confidence():
    config = PersonDetectorConfig(single_leg_weight=0.5, single_leg_offset=0.1)
    det = PersonDetector(config, width_classifier())
    out = det.detect(scene([(2.0, 0.6, 0.06), (2.0, -0.6, 0.06)]))     # 1.2 m apart
    assert out.count == 2
    assert (out.legs[:, 1] == -1).all()
    np.testing.assert_allclose(out.confidence, 0.5 * P_LEG)
    leg_range = np.hypot(*out.leg_xy[out.legs[:, 0]].T)
    np.testing.assert_allclose(np.hypot(*out.xy.T), leg_range + 0.1)
    none = PersonDetector(PersonDetectorConfig(single_legs=False), width_classifier())
    assert none.detect(scene([(2.0, 0.6, 0.06), (2.0, -0.6, 0.06)])).count == 0


def test_each_leg_belongs_to_one_person():
    det = PersonDetector(PersonDetectorConfig(), width_classifier())
    out = det.detect(scene([(2.0, 0.0, 0.06), (2.0, 0.35, 0.06), (2.0, 0.7, 0.06),
                            (2.0, 1.05, 0.06)]))
    assert out.count == 2
    used = out.legs[out.legs >= 0]
    assert len(set(used.tolist())) == used.size == 4


def test_a_lone_leg_next_to_a_pair_adds_no_person():
    det = PersonDetector(PersonDetectorConfig(pair_distance=0.6), width_classifier())
    out = det.detect(scene([(2.0, 0.0, 0.06), (2.0, 0.3, 0.06), (2.0, 0.6, 0.06)]))
    assert out.count == 1 and (out.legs[0] >= 0).all()


def test_people_are_found_as_far_as_the_grid_reaches():
    """A person 9.5 m away (inside the grid's corners, beyond the 8 m its axes reach) is found
    by default and not when the detector stops at 8 m; the default reaches every cell."""
    far = scene([(9.5 * np.cos(0.6) - 0.15 * np.sin(0.6), 9.5 * np.sin(0.6) + 0.15 * np.cos(0.6),
                  0.07),
                 (9.5 * np.cos(0.6) + 0.15 * np.sin(0.6), 9.5 * np.sin(0.6) - 0.15 * np.cos(0.6),
                  0.07)], n_beams=1081, fov=np.radians(270), range_max=30.0)
    assert PersonDetector(PersonDetectorConfig(), width_classifier()).detect(far).count == 1
    near_only = PersonDetector(PersonDetectorConfig(max_range=8.0), width_classifier())
    assert near_only.detect(far).count == 0
    assert PersonDetectorConfig().max_range >= GridConfig().size / np.sqrt(2)


def test_wide_objects_and_thresholds():
    det = PersonDetector(PersonDetectorConfig(), width_classifier())
    assert det.detect(scene(walls=box(2.0, 0.0, 0.4))).count == 0
    strict = PersonDetector(PersonDetectorConfig(threshold=0.99), width_classifier())
    assert strict.threshold == 0.99
    assert strict.detect(scene([(2.0, 0.15, 0.06), (2.0, -0.15, 0.06)])).count == 0
    default = PersonDetector(PersonDetectorConfig(), width_classifier(threshold=0.7))
    assert default.threshold == 0.7 and default.partner_threshold == 0.35


def _leg_at(bearing_deg, distance=1.4, radius=0.06):
    """A leg (x, y, radius) at this bearing (deg) and distance (m) from the scanner."""
    b = np.radians(bearing_deg)
    return (distance * np.cos(b), distance * np.sin(b), radius)


def test_a_segment_cut_by_the_edge_of_the_field_of_view_is_no_lone_leg():
    """A segment that reaches the edge of a 180 deg scanner's view may go on beyond it: the
    end of a wall the robot drives along, cut there, is no person on its own (it is, by its
    width, with view_edge false), but a leg cut there still pairs with the whole leg beside
    it; a leg a few degrees inside the view is a leg, and a 360 deg scanner has no edge."""
    edge = PersonDetector(PersonDetectorConfig(), width_classifier())
    plain = PersonDetector(PersonDetectorConfig(view_edge=False), width_classifier())
    wall_end = scene(walls=[(-2.0, -1.4, 0.15, -1.4)])      # seen from -90 deg to -84 deg
    assert plain.detect(wall_end).count == 1
    out = edge.detect(wall_end)
    assert out.count == 0 and out.leg_probability.tolist() == [edge.partner_threshold]
    for bearing in (-89.0, 89.0):                                        # either edge
        assert plain.detect(scene([_leg_at(bearing)])).count == 1
        assert edge.detect(scene([_leg_at(bearing)])).count == 0
    pair = edge.detect(scene([_leg_at(-89.0), _leg_at(-79.0)]))          # 0.24 m apart
    assert pair.count == 1 and (pair.legs[0] >= 0).all()
    kept = edge.detect(scene([_leg_at(-75.0)]))
    assert kept.count == 1 and kept.leg_probability == pytest.approx([P_LEG])
    n = 720
    seam_leg = _leg_at(-179.8)
    round_scan = scene([seam_leg], walls=box(0.0, 3.0, 0.4), n_beams=n,
                       fov=2 * np.pi * (n - 1) / n, angle_min=-np.pi)
    found = edge.detect(round_scan).xy
    assert (np.hypot(found[:, 0] - seam_leg[0], found[:, 1] - seam_leg[1]) < 0.25).any()


def _without(scan: Scan, taken: np.ndarray) -> tuple[Scan, np.ndarray]:
    """``scan`` with the beams ``taken`` as NaN (the self-mask took them out: the robot's
    body), and their returns per beam (NaN: none), as detection passes them."""
    return (dataclasses.replace(scan, ranges=np.where(taken, np.nan, scan.ranges)),
            np.where(taken, scan.ranges, np.nan))


def test_a_segment_cut_by_the_robots_body_is_no_lone_leg():
    """A segment whose end the robot's own body hides (the body's returns, taken out of the
    scan, lie nearer beside it) may go on behind the body: a lone leg-like piece there is no
    person (it is with masked_edge false), also across a beam without a return and around the
    seam of a 360 deg scan; a person beside the body, two legs, is still found; and a leg
    with the body beyond the 0.15 m beside its end, or with the body farther than itself,
    is a leg."""
    cut = PersonDetector(PersonDetectorConfig(), width_classifier())
    plain = PersonDetector(PersonDetectorConfig(masked_edge=False), width_classifier())
    leg = _leg_at(20.0)                           # 1.4 m away, 2.5 deg either side
    reach = 2.46 + 5.74                           # deg: its half-width and the body's

    def body_at(bearing):                         # a part of the robot 0.5 m away
        return _leg_at(bearing, distance=0.5, radius=0.05)

    for side in (-1.0, 1.0):                      # the body on either side of the leg
        whole = scene([leg, body_at(20.0 + side * (reach + 0.5))])
        scan, body = _without(whole, whole.ranges < 1.0)
        assert plain.detect(scan, body).count == 1
        out = cut.detect(scan, body)
        assert out.count == 0 and out.leg_probability.max() == cut.partner_threshold
        taken = np.flatnonzero(np.isfinite(body))
        edge = taken.max() if side < 0 else taken.min()
        quiet, quiet_body = scan.ranges.copy(), body.copy()
        quiet[edge], quiet_body[edge] = np.inf, np.nan     # a beam without a return between
        assert cut.detect(dataclasses.replace(scan, ranges=quiet), quiet_body).count == 0
        assert cut.detect(scan, body[:-1]).count == 1      # body of another beam count: none
        for garbage in (-body, np.where(np.isfinite(body), np.inf, np.nan), np.zeros_like(body)):
            assert cut.detect(scan, garbage).count == 1   # no taken-out range: nothing cut
    two = scene([leg, _leg_at(30.0), body_at(20.0 - reach - 0.5)])
    pair = cut.detect(*_without(two, two.ranges < 1.0))
    assert pair.count == 1 and (pair.legs[0] >= 0).all()
    apart = scene([leg, body_at(20.0 - reach - 8.0)])
    assert cut.detect(*_without(apart, apart.ranges < 1.0)).count == 1
    behind = scene([leg, _leg_at(20.0 - reach - 0.5, distance=3.0, radius=0.2)])
    assert cut.detect(*_without(behind, behind.ranges > 2.0)).count == 1
    n = 720
    seam = scene([_leg_at(179.0), body_at(179.0 + reach + 0.5)], n_beams=n,
                 fov=2 * np.pi * (n - 1) / n, angle_min=-np.pi)
    scan, body = _without(seam, seam.ranges < 1.0)
    assert plain.detect(scan, body).count == 1 and cut.detect(scan, body).count == 0


def test_disabled_detector_reports_nothing_and_needs_no_model(tmp_path):
    legs = scene([(2.0, 0.15, 0.06), (2.0, -0.15, 0.06)])
    det = PersonDetector(PersonDetectorConfig(enabled=False), width_classifier())
    out = det.detect(legs)
    assert out.count == 0 and out.leg_xy.shape == (0, 2)
    off = PersonDetector(PersonDetectorConfig(enabled=False, model=str(tmp_path / 'no.npz')))
    assert off.detect(legs).count == 0


@pytest.mark.parametrize('ranges', [np.full(361, np.nan), np.full(361, np.inf),
                                    np.full(361, -2.0), np.zeros(361), np.array([1.0])])
def test_scans_without_points_give_no_people(ranges):
    det = PersonDetector()
    with np.errstate(all='raise'):
        out = det.detect(Scan(stamp=1.0, ranges=ranges, angle_min=-1.5,
                              angle_increment=3.0 / max(1, ranges.size - 1), range_min=0.02,
                              range_max=5.6))
    assert out.count == 0 and out.stamp == 1.0


def test_dense_and_garbage_scans_run_with_the_packaged_model():
    det = PersonDetector()
    rng = np.random.default_rng(4)
    for n in (181, 1081, 4000):
        r = rng.uniform(0.0, 6.0, n)
        r[rng.random(n) < 0.2] = np.nan
        out = det.detect(Scan(stamp=0.0, ranges=r, angle_min=-2.3,
                              angle_increment=4.7 / n, range_min=0.02, range_max=5.6))
        assert np.isfinite(out.xy).all() and ((out.confidence >= 0) & (out.confidence <= 1)).all()
        assert out.leg_probability.shape == (out.leg_xy.shape[0],)


def test_config_is_validated():
    with pytest.raises(ConfigError):
        from_dict(PersonDetectorConfig, {'pair_distance': -1.0}, 'person_detector')
    with pytest.raises(ConfigError):
        from_dict(PersonDetectorConfig, {'threshhold': 0.5}, 'person_detector')
    config = from_dict(PersonDetectorConfig, {'threshold': 0.6, 'model': ''}, 'person_detector')
    assert config.threshold == 0.6


# ------------------------------------------------------------------------ real data

def test_finds_the_followed_person_in_a_recording_it_was_not_trained_on():
    from laser_tracker.tools.bench_detector import FOLLOWING, following_frames, score_following

    if not real_recording(FOLLOWING).exists():
        pytest.skip(f'public recording {FOLLOWING} not found (see laser_tracker.tools.data)')
    frames = following_frames()[:1500:3]
    scores = score_following(PersonDetector(), frames)
    assert scores['recall_0.5m'] > 0.6
    assert scores['other_detections_per_scan'] < 0.2
    coarse = score_following(PersonDetector(), frames, np.radians(1.0))
    assert coarse['recall_0.5m'] > 0.6
