"""The detection stage's compiled kernels: the grid evaluated only where it is read equals the
whole grid, Eq. 1 with memory and free window equals it on whole grids, the sums are added as
the numpy formulation added them, bad scans pass, and no scan compiles after the start."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from numba.core.registry import CPUDispatcher

from laser_tracker.core import blobs as blob_kernels
from laser_tracker.core import (difference, egomotion, grid, icp, jit, kalman,
                               person_detector, segmentation, self_mask)
from laser_tracker.core.detections import Blobs, Detections, People, Segments
from laser_tracker.core.hypotheses import HypothesisConfig, HypothesisTracker
from laser_tracker.core.tracking import (association, frame, identity, initiation,
                                         sustaining)
from laser_tracker.core.blobs import BlobConfig
from laser_tracker.core.difference import DifferenceConfig, changed_with_history
from laser_tracker.core.grid import (FREE, OCCUPIED, GridBuilder, GridConfig, GridHistory,
                                     lookup, relative_motion, transform_grid)
from laser_tracker.core.pipeline import Pipeline, PipelineConfig
from laser_tracker.core.scan import Scan
from laser_tracker.core.segmentation import _reduceat

CFG = GridConfig(resolution=0.1, size=8.0, no_return_free=3.0)
N = CFG.cells


def room_scan(stamp, pose=(0.0, 0.0, 0.0), beams=361, movers=(), fov=math.pi, seed=0):
    """A 6 x 5 m room seen from ``pose``, with round ``movers`` (x, y, r) and range noise."""
    x, y, th = pose
    angles = th - fov / 2 + fov / (beams - 1) * np.arange(beams) if beams > 1 else \
        np.array([th])
    d = np.column_stack((np.cos(angles), np.sin(angles)))
    with np.errstate(divide='ignore'):
        tx = np.where(d[:, 0] > 0, (3 - x) / d[:, 0], np.where(d[:, 0] < 0, (-3 - x) / d[:, 0],
                                                                np.inf))
        ty = np.where(d[:, 1] > 0, (2.5 - y) / d[:, 1],
                      np.where(d[:, 1] < 0, (-2.5 - y) / d[:, 1], np.inf))
    r = np.minimum(tx, ty)
    for cx, cy, rad in movers:
        c = np.array([cx - x, cy - y])
        b = d @ c
        disc = b * b - (c @ c - rad * rad)
        r = np.where((disc > 0) & (b > 0), np.minimum(r, b - np.sqrt(np.maximum(disc, 0))), r)
    r = r + np.random.default_rng(seed).normal(0, 0.01, beams)
    inc = fov / (beams - 1) if beams > 1 else 0.01
    return Scan(stamp=stamp, ranges=r, angle_min=-fov / 2 if beams > 1 else 0.0,
                angle_increment=inc, range_min=0.05, range_max=8.0)


def whole(builder: GridBuilder, index: int) -> np.ndarray:
    """Every cell of the grid in buffer ``index`` as the kernels read it (before rendering)."""
    ii, jj = np.meshgrid(np.arange(N), np.arange(N), indexing='ij')
    ij = np.column_stack((ii.ravel(), jj.ravel())).astype(float)
    return lookup(*builder.arrays[:5], np.array([index]), np.zeros((1, 3)), ij, N,
                  CFG.resolution, 0)[0, :, 0].reshape(N, N)


def test_cells_read_where_needed_equal_the_whole_grid():
    builder = GridBuilder(GridConfig(resolution=0.1, size=8.0, no_return_free=3.0,
                                     no_return_bounds=True, lost_echoes=0.0), keep=4)
    scan = room_scan(0.0, movers=[(1.5, 0.3, 0.1)])
    scan.ranges[100:120] = np.inf                      # beams without a return, bounded
    frame = builder.build(scan)
    lazy = whole(builder, frame.index)
    assert (lazy == OCCUPIED).any() and (lazy == FREE).any()
    assert np.array_equal(lazy, frame.grid)            # rendered on request: the same
    # A new beam geometry renders the grids still held: their cells do not change.
    second = builder.build(room_scan(0.1, beams=181))
    before = whole(builder, second.index)
    builder.build(room_scan(0.2, beams=512))
    assert not builder.lazy[second.index]
    assert np.array_equal(whole(builder, second.index), before)
    assert np.array_equal(second.grid, before)


def test_changes_equal_equation_1_with_memory_and_free_window_on_whole_grids():
    """The kernel's changed cells (memory, free window, motion) equal the rule applied to
    the whole earlier grids brought into the current frame by scipy's affine transform."""
    config = DifferenceConfig(memory=2, free_window=0.25, motion_depth=0.0)
    builder = GridBuilder(CFG, keep=6)
    history = GridHistory(builder, 5)
    found = 0
    for k in range(9):
        pose = np.array([0.05 * k, -0.02 * k, 0.01 * k])
        scan = room_scan(0.1 * k, pose, movers=[(-1.0 + 0.3 * k, 0.5, 0.15)], seed=k)
        frame = builder.build(scan, pose)
        cells = changed_with_history(frame, scan.stamp, pose, history, config)
        if len(history):
            earlier = [(f, relative_motion(builder.meta[f.index], pose)) for f in history.frames]
            moved = [transform_grid(f.grid, m, CFG.resolution) for f, m in earlier]
            n_free = 1 + sum(scan.stamp - builder.meta[f.index, 3] <= config.free_window
                             for f in list(history.frames)[1:])
            n_occ = min(len(moved), config.memory + 1)
            now = np.zeros(N * N, bool)
            now[frame.flat] = True
            rule = now.reshape(N, N) & np.any([g == FREE for g in moved[:n_free]], axis=0) & \
                ~np.any([g == OCCUPIED for g in moved[:n_occ]], axis=0)
            assert cells.tolist() == np.flatnonzero(rule).tolist(), k
            found += cells.size
        history.push(frame)
    assert found > 0                                   # the walker made changes


def test_cluster_sums_add_as_numpy_reduceat():
    rng = np.random.default_rng(2)
    for n in list(range(1, 40)) + [129, 300]:
        values = rng.normal(size=n + 5) * 10.0 ** rng.integers(-3, 4, size=n + 5)
        assert _reduceat(values, 3, 3 + n - 1) == np.add.reduceat(values[3:3 + n], [0])[0]


def _blas_in_avx512_order() -> bool:
    rng = np.random.default_rng(0)
    pairs = [(rng.normal(size=999), rng.normal(size=999)) for _ in range(3)]
    return all(jit.blas_dot(x, y, x.size) == x @ y for x, y in pairs)


@pytest.mark.skipif(not _blas_in_avx512_order(),
                    reason="numpy's BLAS on this machine does not add in OpenBLAS's AVX-512 "
                    "order (the kernels give the same numbers on every machine)")
def test_surface_sums_add_as_numpys_matrix_product():
    """A blob's surface moments equal ``w @ features`` of the numpy formulation bit for bit,
    for one blob (numpy calls gemv) and for several (gemm)."""
    rng = np.random.default_rng(4)
    config = BlobConfig()
    settings = blob_kernels.settings_of(config)
    for trial in range(60):
        n = int(rng.integers(8, 700))
        angles = np.linspace(-1.5, 1.5, n)
        r = 2.0 + np.cumsum(rng.normal(0, 0.03, n))
        points = np.column_stack((r * np.cos(angles), r * np.sin(angles)))
        ids, starts = blob_kernels._surface_ids(points, config.surface_gap)
        b = 1 if trial % 2 else int(rng.integers(2, 6))
        centroids = points[rng.integers(0, n, b)] + rng.normal(0, 0.05, (b, 2))
        shape = blob_kernels._surface_shape(points, ids, starts, centroids, settings,
                                            0.1)
        d = centroids[:, None, :] - points[None, :, :]
        d2 = np.einsum('bmk,bmk->bm', d, d)
        near = d2.argmin(axis=1)
        sid = np.where(d2[np.arange(b), near] <= 2.0 * 0.1 ** 2, ids[near], -1)
        w = (ids[None, :] == sid[:, None]) & (sid >= 0)[:, None] & \
            (d2 <= config.surface_radius ** 2)
        feats = np.column_stack((points, points * points, points[:, 0] * points[:, 1]))
        m = (w.astype(np.float64) @ feats) / np.maximum(w.sum(axis=1), 1)[:, None]
        np.testing.assert_array_equal(shape[1], m[:, 0])
        np.testing.assert_array_equal(shape[2], m[:, 1])
        np.testing.assert_array_equal(shape[3], m[:, 2] - m[:, 0] * m[:, 0])
        np.testing.assert_array_equal(shape[5], m[:, 4] - m[:, 0] * m[:, 1])


def _garbage(beams: int, seed: int) -> np.ndarray:
    """Ranges with NaN, +inf, -inf, 0, below range_min and at range_max mixed in."""
    rng = np.random.default_rng(seed)
    r = rng.uniform(0.2, 7.0, beams)
    for value, share in ((np.nan, 0.1), (np.inf, 0.1), (-np.inf, 0.05), (0.0, 0.05),
                         (0.01, 0.05), (8.0, 0.05)):
        r[rng.random(beams) < share] = value
    return r


@pytest.mark.parametrize('paper', [False, True])
def test_bad_scans_and_a_beam_count_that_changes_pass_detection(paper):
    config = PipelineConfig()
    if paper:
        from laser_tracker.parameters import PAPER_REFERENCE
        config = config.replace(**{s: {k.split('.')[1]: v for k, v in PAPER_REFERENCE[
            'detection'].items() if k.startswith(s + '.')}
            for s in ('grid', 'difference', 'blobs', 'person_detector')})
    config = config.replace(grid={'lost_echoes': 0.0, 'free_erosion': 3} if not paper else {})
    pipeline = Pipeline(config)
    t = 0.0
    runs = [(361, 'room'), (1, 'room'), (3, 'room'), (4096, 'room'), (4096, 'garbage'),
            (361, 'invalid'), (361, 'room'), (181, 'garbage'), (1, 'invalid'), (3, 'garbage'),
            (768, 'room'), (768, 'room')]
    reported = 0
    for k, (beams, kind) in enumerate(runs):
        t += 0.1
        fov = 2 * math.pi * (1 - 1 / beams) if beams == 4096 else math.pi
        scan = room_scan(t, beams=beams, fov=fov, movers=[(1.0, -1.5 + 0.2 * k, 0.12)], seed=k)
        if kind == 'garbage':
            scan.ranges[:] = _garbage(beams, k)
        elif kind == 'invalid':
            scan.ranges[:] = np.resize([np.nan, np.inf, -np.inf, 0.0, 0.01, 8.0], beams)
        pipeline.add_odometry(t, (0.0, 0.0, 0.0))
        r = pipeline.step(scan, want_grids=k % 2 == 0)
        det = r.detection
        d = r.detections
        b = d.blobs
        assert np.isfinite(b.xy).all() and np.isfinite(d.people.xy).all()
        assert np.isfinite(d.segments.xy).all() and len(d.segments) == d.segments.leg.size
        assert not np.isinf(b.structure).any() and np.isfinite(d.people.confidence).all()
        if det.grid is not None:
            assert det.grid.shape == (config.grid.cells,) * 2
            assert set(np.unique(det.grid)) <= {0, 1, 2}
        if kind == 'invalid':
            assert b.count == 0 and d.segments.xy.shape == (0, 2)
        reported += r.skipped is None
    assert reported >= len(runs) - 3                   # at most the ego-motion's own skips


@pytest.mark.parametrize('paper', [False, True])
@pytest.mark.parametrize('beams, kind', [(1, 'room'), (3, 'room'), (4096, 'room'),
                                         (361, 'invalid'), (3, 'invalid'),
                                         (4096, 'garbage')])
def test_a_stream_of_bad_scans_from_its_first_scan_runs_through_every_stage(beams, kind,
                                                                             paper):
    """A stream that starts with (and keeps) scans of 1, 3 or 4,096 beams, or with every
    beam invalid, on a moving robot: every scan passes every stage (the ego-motion's pose
    chain starts and goes on, coasting where nothing can be matched), nothing non-finite is
    reported, and the normal scans after them get poses and detections."""
    config = PipelineConfig()
    if paper:
        config = PipelineConfig.load(Path(__file__).resolve().parents[1] / 'config'
                                     / 'paper_reference.yaml')
    pipeline = Pipeline(config)
    results = []
    for k in range(8):
        t = 0.1 * (k + 1)
        pose = (0.03 * k, 0.0, 0.01 * k)
        fov = 2 * math.pi * (1 - 1 / beams) if beams == 4096 else math.pi
        scan = room_scan(t, pose, beams=beams if k < 5 else 361, fov=fov if k < 5 else math.pi,
                         movers=[(1.0, -1.5 + 0.2 * k, 0.12)], seed=k)
        if k < 5 and kind == 'garbage':
            scan.ranges[:] = _garbage(beams, k)
        elif k < 5 and kind == 'invalid':
            scan.ranges[:] = np.resize([np.nan, np.inf, -np.inf, 0.0, 0.01, 8.0], beams)
        pipeline.add_odometry(t, pose)
        results.append(pipeline.step(scan, want_grids=k % 2 == 0))
    for r in results:
        assert r.skipped is None, r.skipped
        assert np.isfinite(r.pose).all() and np.isfinite(r.ego.pose_covariance).all()
        d = r.detections
        assert np.isfinite(d.blobs.xy).all() and np.isfinite(d.people.xy).all()
        assert np.isfinite(d.segments.xy).all()
        assert np.isfinite(r.hypotheses.position).all()
    if kind == 'invalid':
        assert [r.source for r in results[:5]] == ['init'] + ['odometry'] * 4
        assert all(r.detections.blobs.count == 0 for r in results[:5])
    assert results[-1].source == 'icp'


def test_no_scan_compiles_after_the_start():
    """Every kernel a scan calls was compiled (or loaded from the cache) when the stage was
    made: the first scans run at full speed."""
    modules = (grid, difference, blob_kernels, segmentation, person_detector, icp, self_mask,
               egomotion, kalman, association, frame, identity, initiation, sustaining)
    Pipeline()

    def signatures():
        return {f'{m.__name__}.{name}': len(f.signatures) for m in modules
                for name, f in vars(m).items() if isinstance(f, CPUDispatcher)}

    before = signatures()
    pipeline = Pipeline(PipelineConfig())
    t = 0.0
    for k, beams in enumerate((361, 361, 361, 768, 768)):
        t += 0.1
        scan = room_scan(t, (0.02 * k, 0.0, 0.0), beams=beams,
                         movers=[(1.0, -1.5 + 0.3 * k, 0.1), (1.2, -1.2 + 0.3 * k, 0.06)],
                         seed=k)
        scan.ranges[::17] = np.nan
        scan.ranges[5::23] = np.inf
        pipeline.add_odometry(t, (0.02 * k, 0.0, 0.0))
        pipeline.step(scan, want_grids=k == 3)
    assert signatures() == before
    _track_walkers_and_a_stop()          # every role of the tracker, with 0 to many rows
    assert signatures() == before


def _track_walkers_and_a_stop():
    """Two walkers (two legs each, detected as people, splitting and merging), one who
    stops (held by a segment), a mover alone, on a moving scanner."""
    tracker = HypothesisTracker(HypothesisConfig(confirm_min_travel=0.0, person_min_travel=0.0,
                                                 new_when_ungated=True, gait_spread=0.05))
    for k in range(20):
        t = 0.1 * k
        walkers = [(1.0 + 0.1 * k, 0.5), (2.0, -1.0 + 0.12 * k)]
        stop = (3.0 + 0.1 * min(k, 8), 1.0)
        legs = [(x + dx, y) for x, y in walkers for dx in (-0.1, 0.1)]
        blobs = np.array(legs + ([stop] if k < 8 else []) + [(0.5 * k, -3.0)])
        people = np.array(walkers + ([stop] if k % 3 else []))
        det = Detections(stamp=t, origin=np.array([0.05 * k, 0.0, 0.01 * k]),
                         blobs=Blobs(xy=blobs, cells=np.full(len(blobs), 3),
                                     extent=np.full(len(blobs), 0.1),
                                     structure=np.where(np.arange(len(blobs)) % 2, 0.3,
                                                        np.nan)))
        det.people = People(xy=people, confidence=np.full(len(people), 0.9),
                            free=np.arange(len(people)) == 0, spread=np.full(len(people), 0.2),
                            static=np.zeros(len(people), bool))
        det.segments = Segments(xy=np.array(legs + [stop]), leg=np.full(len(legs) + 1, 0.5))
        tracker.update(det)


def test_a_person_walked_in_only_where_a_beam_went_on_beyond_the_scanners_displacement():
    """From a scanner that drove 0.4 m, a leg 0.25 m in front of the wall its earlier beam
    hit has not walked in with ``motion_depth`` 1 (parallax: the beam may have passed beside
    something there); a leg in open space, 1.7 m in front of the wall, has."""
    from laser_tracker.core.difference import people_in_odometry
    from laser_tracker.core.person_detector import PersonDetections

    builder = GridBuilder(CFG, keep=4)
    history = GridHistory(builder, 3)
    for k, pose in enumerate((np.zeros(3), np.array([0.4, 0.0, 0.0]))):
        history.push(builder.build(room_scan(0.1 * k, pose, seed=k), pose))
    people = PersonDetections.empty(0.1)
    people.leg_xy = np.array([[2.35, 0.05], [0.8, 0.05]])      # world x 2.75 and 1.2
    people.xy = people.leg_xy.copy()
    people.legs = np.array([[0, -1], [1, -1]])
    walked = {depth: people_in_odometry(people, (0.4, 0.0, 0.0), 0.1, history, None,
                                        depth)[1].tolist() for depth in (0.0, 1.0)}
    assert walked == {0.0: [True, True], 1.0: [False, True]}
