"""Blob segmentation: 4-connected components, centroids, surfaces and the structure test."""
from __future__ import annotations

import logging
import math

import numpy as np
from scipy import ndimage

from laser_tracker.core.blobs import (BlobConfig, Blobs, label_cells, segment,
                                      surface_centroids)
from laser_tracker.core.geometry import points_in_frame

N = 100
RES = 0.1


def flat_of(cells):
    return np.unique(np.array([i * N + j for i, j in cells], dtype=np.intp))


def centre(i, j):
    return np.array([(i + 0.5 - N / 2) * RES, (j + 0.5 - N / 2) * RES])


def test_label_cells_is_4_connected():
    cells = [(10, 10), (10, 11), (11, 11),      # an L: one blob
             (12, 12),                          # diagonal to (11, 11): a separate blob
             (40, 5), (42, 5),                  # a gap of one row: two blobs
             (60, 60), (60, 61), (60, 62)]      # a row
    count, labels, sides = label_cells(flat_of(cells), N)
    assert count == 5
    groups = {}
    for f, lab in zip(flat_of(cells), labels):
        groups.setdefault(lab, set()).add(divmod(int(f), N))
    assert sorted(map(len, groups.values())) == [1, 1, 1, 3, 3]
    assert {(10, 10), (10, 11), (11, 11)} in groups.values()
    assert sorted(sides.tolist()) == [1, 1, 1, 2, 3]          # larger side of each box


def test_compressed_labelling_equals_labelling_the_full_map():
    rng = np.random.default_rng(11)
    for _ in range(20):
        flat = np.unique(rng.choice(N * N, rng.integers(1, 150), replace=False))
        full = np.zeros(N * N, np.uint8)
        full[flat] = 1
        ref, ref_count = ndimage.label(full.reshape(N, N),
                                       structure=ndimage.generate_binary_structure(2, 1))
        count, labels, sides = label_cells(flat, N)
        assert count == ref_count
        # The same components, numbered as scipy numbers them (raster order).
        assert np.array_equal(labels + 1, ref.reshape(-1)[flat])
        boxes = ndimage.find_objects(ref)
        assert sides.tolist() == [max(b[0].stop - b[0].start, b[1].stop - b[1].start)
                                  for b in boxes]


def test_segment_centroids_sizes_extents_in_the_odometry_frame():
    cfg = BlobConfig(position='changed')
    cells = [(60, 50), (60, 51), (61, 50), (61, 51), (30, 70)]
    origin = np.array([10.0, -2.0, math.pi / 2])       # scanner at (10, -2) facing +y
    blobs = segment(flat_of(cells), N, RES, origin, 5.0, cfg)
    assert isinstance(blobs, Blobs) and blobs.count == 2
    order = np.argsort(-blobs.cells)
    assert blobs.cells[order].tolist() == [4, 1]
    local_big = (centre(60, 50) + centre(61, 51)) / 2       # (1.05, 0.05) in the scanner frame
    expected = np.array([10.0 - local_big[1], -2.0 + local_big[0]])
    assert np.allclose(blobs.xy[order[0]], expected)
    assert np.allclose(points_in_frame(origin, blobs.xy)[order[0]], local_big)
    assert np.allclose(blobs.extent[order], [0.2, 0.1])
    assert np.isnan(blobs.structure).all()                   # no scan points: no structure


def test_min_and_max_blob_size_and_the_bound_on_blobs(caplog):
    cells = [(10, 10)] + [(20, j) for j in range(10)] + [(40 + 2 * k, 80) for k in range(20)]
    flat = flat_of(cells)
    only_big = segment(flat, N, RES, np.zeros(3), 0.0, BlobConfig(min_cells=2))
    assert only_big.cells.tolist() == [10]
    no_huge = segment(flat, N, RES, np.zeros(3), 0.0, BlobConfig(max_cells=5))
    assert no_huge.count == 21 and no_huge.cells.max() == 1
    with caplog.at_level(logging.WARNING, logger='laser_tracker.core.blobs'):
        bounded = segment(flat, N, RES, np.zeros(3), 0.0, BlobConfig(max_blobs=5))
    assert bounded.count == 5 and bounded.dropped == 17
    assert bounded.cells.max() == 10                       # the largest are kept
    assert any('max_blobs' in r.message for r in caplog.records)


def arc_points(cx, cy, radius, n=9, facing=math.pi):
    a = facing + np.linspace(-0.8, 0.8, n)
    return np.column_stack((cx + radius * np.cos(a), cy + radius * np.sin(a)))


def wall_points(x, y0, y1, step=0.03):
    ys = np.arange(y0, y1, step)
    return np.column_stack((np.full(ys.size, x), ys))


def test_surface_position_is_the_visible_surface_centroid():
    cfg = BlobConfig(centre_offset=0.0)
    leg = arc_points(2.0, 0.5, 0.06)               # a leg's front arc, seen from the origin
    points = np.vstack((wall_points(4.0, -1.0, 0.3), leg, wall_points(4.0, 0.8, 2.0)))
    # A blob on the leg's leading edge only.
    blob = leg[:2].mean(axis=0, keepdims=True)
    pos, wall = surface_centroids(blob, points, cfg, RES)
    assert np.allclose(pos[0], leg.mean(axis=0))
    assert np.isnan(wall[0])                     # a leg is a clump, not a wall


def test_centre_offset_moves_the_position_behind_the_surface():
    face = np.column_stack((np.full(21, 3.0), np.linspace(-0.25, 0.25, 21)))  # 0.5 m face
    blob = np.array([[3.0, 0.2]])
    pos0, _ = surface_centroids(blob, face, BlobConfig(centre_offset=0.0), RES)
    pos, _ = surface_centroids(blob, face, BlobConfig(centre_offset=0.3), RES)
    assert np.allclose(pos0[0], [3.0, 0.0], atol=1e-9)
    width = np.sqrt(12 * np.var(face[:, 1]))     # ~0.5 m
    assert np.allclose(pos[0], [3.0 + 0.3 * width, 0.0], atol=1e-6)


def test_structure_marks_a_wall_but_not_a_flank_leading_edge():
    cfg = BlobConfig()
    wall = wall_points(3.0, -2.0, 2.0)           # a long wall along y at x = 3
    blob_mid = np.array([[3.0, 0.01]])
    _, angle = surface_centroids(blob_mid, wall, cfg, RES)
    assert abs(abs(math.cos(angle[0])) - 0.0) < 0.05      # along y: angle ~ pi/2
    # A robot's flank: a 0.55 m stretch with the blob at its leading end (y = 0.55).
    flank = wall_points(2.0, 0.0, 0.56)
    _, angle = surface_centroids(np.array([[2.0, 0.54]]), flank, cfg, RES)
    assert np.isnan(angle[0])


def test_two_changed_components_on_one_surface_are_one_blob():
    cfg = BlobConfig(position='surface')
    flank = wall_points(2.0, 0.0, 0.5)
    cells = [(70, 50), (70, 54)]                 # two separate changed cells on the flank
    blobs = segment(flat_of(cells), N, RES, np.zeros(3), 0.0, cfg, flank)
    assert blobs.count == 1 and blobs.cells.tolist() == [2]
    split = segment(flat_of(cells), N, RES, np.zeros(3), 0.0, BlobConfig(position='changed'),
                    flank)
    assert split.count == 2


def test_empty_difference_gives_no_blobs():
    blobs = segment(np.zeros(0, np.intp), N, RES, np.zeros(3), 1.0, BlobConfig())
    assert blobs.count == 0 and blobs.xy.shape == (0, 2)
