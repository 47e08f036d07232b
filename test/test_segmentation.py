"""Scan segmentation and cluster features (laser_tracker.core.segmentation)."""
import math

import numpy as np
import pytest
from leg_scenes import box, scene

from laser_tracker.core.scan import Scan
from laser_tracker.core.segmentation import (CLEARANCE, FEATURE_NAMES, LEG_WIDTH, MAX_CLEAR,
                                             MAX_RADIUS, MAX_WINDOW_ANGLE, segment,
                                             window_min)

F = {name: i for i, name in enumerate(FEATURE_NAMES)}


def reference_clusters(scan: Scan, jump=0.13, min_points=3, max_width=1.0, max_range=None):
    """Features cluster by cluster with plain loops and numpy.linalg, from their definitions."""
    valid = scan.valid()
    beams = np.flatnonzero(valid)
    angles = scan.angles[beams]
    r = scan.ranges[beams]
    pts = np.column_stack((r * np.cos(angles), r * np.sin(angles)))
    groups, current = [], [0]
    for i in range(1, len(pts)):
        if np.linalg.norm(pts[i] - pts[i - 1]) > jump:
            groups.append(current)
            current = []
        current.append(i)
    if len(pts):
        groups.append(current)
    free = np.where(valid, scan.ranges, np.inf)
    da = abs(scan.angle_increment)
    rows = []
    for g in groups:
        p = pts[g]
        n = len(g)
        c = p.mean(axis=0)
        width = np.linalg.norm(p[-1] - p[0])
        dist = np.linalg.norm(c)
        if n < min_points or width > max_width or (max_range is not None and dist > max_range):
            continue
        line_rms = math.sqrt(max(np.linalg.eigvalsh(np.cov(p.T, bias=True))[0], 0.0))
        a = np.column_stack((p, np.ones(n)))
        sol = np.linalg.lstsq(a, -(p ** 2).sum(axis=1), rcond=None)[0]
        centre = -sol[:2] / 2
        radius = math.sqrt(max(centre @ centre - sol[2], 0.0))
        if np.linalg.matrix_rank(a) < 3 or radius > MAX_RADIUS:
            radius, circle_rms = MAX_RADIUS, line_rms
        else:
            algebraic = ((p - centre) ** 2).sum(axis=1) - radius ** 2
            circle_rms = math.sqrt(np.mean(algebraic ** 2)) / (2 * radius)
        steps = np.linalg.norm(np.diff(p, axis=0), axis=1)
        chord = (p[-1] - p[0]) / width
        normal = np.array([-chord[1], chord[0]])
        toward = 1.0 if normal @ (-p[0]) >= 0 else -1.0
        bulge = np.sum((p - p[0]) @ normal) / (n - 1) * toward / width
        clear = []
        for b, end, side in ((beams[g[0]], p[0], -1), (beams[g[-1]], p[-1], +1)):
            end_r = np.linalg.norm(end)
            span = int(min(math.ceil(CLEARANCE / (end_r * da)), math.ceil(MAX_WINDOW_ANGLE / da)))
            window = range(b - span, b) if side < 0 else range(b + 1, b + span + 1)
            window = [i for i in window if 0 <= i < scan.n_beams]
            nearest = min((free[i] for i in window), default=np.inf)
            clear.append(float(np.clip(nearest - end_r, -MAX_CLEAR, MAX_CLEAR)))
        rows.append([n * dist * da / LEG_WIDTH, width, line_rms, radius, circle_rms,
                     steps.sum() / width, steps.std() / steps.mean(), bulge, dist,
                     float(sum(x < 0 for x in clear)), min(clear), max(clear)])
    return np.array(rows).reshape(-1, len(FEATURE_NAMES))


SCENES = [
    scene([(2.0, 0.15, 0.06), (2.1, -0.2, 0.06), (1.0, 1.2, 0.1)],
          walls=[(4, -4, 4, 4), *box(3.0, 1.5, 0.4)], noise=0.01),
    scene([(1.5, 0.0, 0.07), (3.0, 0.05, 0.05)], walls=box(2.0, -1.5, 0.3), n_beams=181,
          noise=0.02, seed=1),
    scene([(0.8, 0.3, 0.06), (0.9, 0.55, 0.06)], walls=[(-1, 3, 5, 3), (5, 3, 5, -3)],
          n_beams=1081, fov=np.radians(270), noise=0.005, seed=2),
]


@pytest.mark.parametrize('s', SCENES)
def test_vectorised_features_equal_their_definitions(s):
    clusters = segment(s, 0.13, 3, 1.0)
    expected = reference_clusters(s)
    assert clusters.count == expected.shape[0] > 0
    np.testing.assert_allclose(clusters.features, expected, rtol=1e-6, atol=1e-9)
    assert np.isfinite(clusters.features).all()


def test_jump_distance_splits_clusters():
    two = scene([(2.0, 0.0, 0.1), (2.0, 0.32, 0.1)])        # surfaces about 0.12 m apart
    assert segment(two, jump_distance=0.05).count == 2
    assert segment(two, jump_distance=0.5).count == 1


def test_leg_features_do_not_depend_on_beam_density():
    """The same leg seen at 0.25, 0.5 and 1 degree between beams (no noise)."""
    rows = []
    for n in (721, 361, 181):
        c = segment(scene([(2.0, 0.0, 0.06)], n_beams=n))
        assert c.count == 1
        rows.append(c.features[0])
    rows = np.array(rows)
    np.testing.assert_allclose(rows[:, F['circle_radius']], 0.06, rtol=1e-6)
    np.testing.assert_allclose(rows[:, F['circle_rms']], 0.0, atol=1e-6)
    # the ends are sampled: width and n_rel may be off by about one beam spacing (2 m * 1 deg)
    for name, tol in (('n_rel', 0.5), ('width', 0.04), ('distance', 0.01)):
        assert np.ptp(rows[:, F[name]]) <= tol, (name, rows[:, F[name]])
    # the visible arc between the outermost samples shrinks with 3 or 4 points (1 degree)
    assert abs(rows[0, F['bulge']] - rows[1, F['bulge']]) < 0.02
    assert 0.05 < rows[2, F['bulge']] < rows[1, F['bulge']]
    # a raw point count would differ fourfold; n_rel stays near 1 for a 0.12 m leg
    assert np.all(np.abs(rows[:, F['n_rel']] - 1.0) < 0.5)


def test_shape_features_tell_a_leg_from_a_flat_surface():
    c = segment(scene([(2.0, 0.0, 0.06)], walls=[(3.0, 1.0, 3.0, 1.4)]))
    leg, flat = (0, 1) if c.xy[0, 1] < c.xy[1, 1] else (1, 0)
    assert c.features[leg, F['bulge']] > 0.1            # bulges towards the scanner
    assert abs(c.features[flat, F['bulge']]) < 0.01
    assert c.features[flat, F['circle_radius']] == MAX_RADIUS
    assert c.features[flat, F['line_rms']] < 1e-9
    assert c.features[leg, F['clear_min']] == MAX_CLEAR   # nothing beside it


def test_occluded_end_is_flagged():
    """A pole in front hides one side of a leg: that end has a nearer return beside it."""
    s = scene([(2.0, 0.0, 0.06), (1.2, 0.11, 0.03)])
    c = segment(s, 0.13, 3, 1.0)
    leg = int(np.argmin(np.abs(c.xy[:, 0] - 1.95)))
    assert c.features[leg, F['occluded_ends']] == 1
    assert c.features[leg, F['clear_min']] < 0
    assert c.occluded[leg].sum() == 1


def test_size_and_range_filters():
    s = scene([(2.0, 0.0, 0.06), (6.0, 1.0, 0.06)], walls=[(3, -3, 3, -0.5)])
    assert segment(s, max_width=1.0).count == 2                      # the wall is too wide
    assert segment(s, max_width=10.0).count == 3
    assert segment(s, max_width=1.0, max_range=4.0).count == 1
    c = segment(s, max_width=10.0)
    wall = int(np.argmax(c.features[:, F['width']]))
    assert c.features[wall, F['circle_radius']] == MAX_RADIUS
    assert np.isfinite(c.features).all()
    assert segment(s, min_points=1000).count == 0


def _scan(ranges, **kw):
    ranges = np.asarray(ranges, dtype=float)
    return Scan(stamp=0.0, ranges=ranges, angle_min=-1.0, angle_increment=2.0 / ranges.size,
                range_min=kw.get('range_min', 0.05), range_max=kw.get('range_max', 8.0))


@pytest.mark.parametrize('ranges', [
    np.full(361, np.nan),
    np.full(361, np.inf),
    np.full(361, 8.0),                      # all at range_max: no return
    np.full(361, -1.0),
    np.full(361, 0.01),                     # below range_min
    np.r_[np.full(359, np.nan), 2.0, 2.0],  # two points
    np.array([2.0]),
])
def test_scans_without_usable_clusters(ranges):
    c = segment(_scan(ranges))
    assert c.count == 0 and c.features.shape == (0, len(FEATURE_NAMES))


def test_garbage_scans_give_finite_features():
    rng = np.random.default_rng(3)
    for n in (181, 361, 1081, 2000):
        r = rng.uniform(-1, 9, n)
        r[rng.random(n) < 0.1] = np.nan
        r[rng.random(n) < 0.1] = np.inf
        r[rng.random(n) < 0.05] = 0.0
        smooth = np.where(rng.random(n) < 0.5, 3.0 + 0.01 * rng.standard_normal(n), r)
        for ranges in (r, smooth):
            with np.errstate(all='raise'):      # no floating point warning escapes
                c = segment(_scan(ranges), max_width=20.0)
            assert np.isfinite(c.features).all() and np.isfinite(c.xy).all()
            assert ((c.first >= 0) & (c.last < n) & (c.first <= c.last)).all()


def test_collinear_and_repeated_points():
    ranges = np.full(101, np.inf)
    ranges[40:60] = 2.0 / np.cos(np.linspace(-0.1, 0.1, 20))    # a straight wall piece
    c = segment(Scan(stamp=0.0, ranges=ranges, angle_min=-0.5, angle_increment=0.01,
                     range_min=0.0, range_max=8.0))
    assert c.count == 1
    assert c.features[0, F['circle_radius']] == MAX_RADIUS
    assert np.isfinite(c.features).all()


def test_window_min_matches_brute_force():
    rng = np.random.default_rng(0)
    values = rng.random(300)
    values[rng.random(300) < 0.2] = np.inf
    lo = rng.integers(0, 301, 500)
    hi = np.clip(lo + rng.integers(-3, 80, 500), -1, 299)
    expected = [values[a:b + 1].min() if b >= a else np.inf for a, b in zip(lo, hi)]
    np.testing.assert_array_equal(window_min(values, lo, hi), expected)


def test_scanning_direction_does_not_matter():
    s = SCENES[0]
    reverse = Scan(stamp=0.0, ranges=s.ranges[::-1],
                   angle_min=s.angle_min + (s.n_beams - 1) * s.angle_increment,
                   angle_increment=-s.angle_increment, range_min=s.range_min,
                   range_max=s.range_max)
    a, b = segment(s), segment(reverse)
    assert a.count == b.count > 0
    np.testing.assert_allclose(a.features[np.lexsort(a.xy.T)], b.features[np.lexsort(b.xy.T)],
                               atol=1e-9)


def test_a_scan_that_closes_the_circle_is_segmented_around_its_seam():
    """A 360 deg scanner whose scans start straight ahead: a leg on the seam, one just beside
    it, and a nearer object just across the seam from a third leg's end (its clearance is
    found around the seam). Its clusters and their features are those of the same scan
    started behind the scanner, and a cluster on the seam runs from the last beams to the
    first ones."""
    n = 720
    things = dict(circles=((2.0, 0.0, 0.06), (2.0, 0.3, 0.06), (3.0, -0.25, 0.06),
                           (1.5, 0.12, 0.05)),
                  walls=((4.0, -3.0, 4.0, 3.0),), n_beams=n, fov=2 * np.pi * (n - 1) / n)
    ahead = scene(**things, angle_min=0.0)
    behind = Scan(stamp=0.0, ranges=np.roll(ahead.ranges, n // 2), angle_min=-np.pi,
                  angle_increment=ahead.angle_increment, range_min=ahead.range_min,
                  range_max=ahead.range_max)
    a, b = segment(ahead), segment(behind)
    assert a.count == b.count >= 4
    order_a, order_b = np.lexsort(a.xy.T), np.lexsort(b.xy.T)
    np.testing.assert_allclose(a.xy[order_a], b.xy[order_b], atol=1e-9)
    np.testing.assert_allclose(a.features[order_a], b.features[order_b], atol=1e-9)
    on_seam = np.argmin(np.hypot(*(a.xy - (2.0, 0.0)).T))
    assert a.first[on_seam] > a.last[on_seam]           # from the last beams to the first
    assert a.n_points[on_seam] == a.last[on_seam] + n - a.first[on_seam] + 1
    # a scan one beam short of the circle does not close it: the seam splits that leg
    short = Scan(stamp=0.0, ranges=ahead.ranges[:-2], angle_min=0.0,
                 angle_increment=ahead.angle_increment, range_min=ahead.range_min,
                 range_max=ahead.range_max)
    assert np.hypot(*(segment(short).xy - (2.0, 0.0)).T).min() > 0.01


def test_a_lone_object_on_the_seam_of_a_360_degree_scan_is_one_cluster_in_beam_order():
    """A person alone in the open, on the seam of a 360 deg scanner: every return is on
    them, so no two returns lie apart; their cluster still runs from the last beams to the
    first ones, with the features of the same leg anywhere else in the scan."""
    n = 720
    fov = 2 * np.pi * (n - 1) / n
    on_seam = segment(scene(circles=((-1.4, 0.0, 0.06),), n_beams=n, fov=fov,
                            angle_min=-np.pi))
    elsewhere = segment(scene(circles=((0.0, 1.4, 0.06),), n_beams=n, fov=fov,
                              angle_min=-np.pi))
    assert on_seam.count == elsewhere.count == 1
    assert on_seam.first[0] > on_seam.last[0]
    np.testing.assert_allclose(on_seam.features, elsewhere.features, atol=0.02)
    assert on_seam.feature('width')[0] > 0.08
