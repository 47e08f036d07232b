"""Occupancy grid: ray casting (FREE / OCCUPIED / UNKNOWN), the previous grid in the current
frame, and the difference map (Equation 1)."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from laser_tracker.core.difference import DifferenceConfig, changed_cells, difference_map
from laser_tracker.core.grid import (FREE, OCCUPIED, PAD, UNKNOWN, GridBuilder, GridConfig,
                                     build_grid, lookup_grid, ray_table, transform_grid)
from laser_tracker.core.scan import Scan

RES = 0.1
CFG = GridConfig(resolution=RES, size=8.0, free_margin=0.1, no_return_free=3.0,
                 free_erosion=0, no_return_bounds=False)
N = CFG.cells  # 80 cells, the scanner at the grid centre


def cell_of(x, y, n=N, res=RES):
    return int(math.floor(x / res + n / 2)), int(math.floor(y / res + n / 2))


def scan_180(ranges, stamp=0.0, range_max=8.0):
    ranges = np.asarray(ranges, dtype=float)
    n = ranges.size
    return Scan(stamp=stamp, ranges=ranges, angle_min=-math.pi / 2,
                angle_increment=math.pi / (n - 1), range_min=0.05, range_max=range_max)


def test_ray_casting_marks_free_occupied_and_unknown():
    ranges = np.full(181, 3.0)             # 1 deg beams: a circle of returns at 3 m ...
    ranges[85:96] = 2.0                    # ... an object straight ahead at 2 m ...
    ranges[150:] = np.nan                  # ... and no information left of 60 deg
    grid = build_grid(scan_180(ranges), CFG)
    assert grid.shape == (N, N)
    # The cells of the returns are occupied.
    assert grid[cell_of(2.0, 0.0)] == OCCUPIED
    assert grid[cell_of(3.0, 0.0)] != OCCUPIED        # hidden behind the object
    assert grid[cell_of(0.0, -3.0)] == OCCUPIED
    # Cells the beams passed through are free ...
    for x, y in ((0.35, 0.02), (1.05, 0.02), (1.75, -0.02), (2.0, 1.2), (0.5, -2.5)):
        assert grid[cell_of(x, y)] == FREE, (x, y)
    # ... but not within free_margin of a return, nor in the object's shadow, nor behind
    # the 3 m circle, nor where the beams returned nothing, nor behind the scanner.
    assert grid[cell_of(1.95, 0.02)] in (OCCUPIED, UNKNOWN)
    for x, y in ((2.45, 0.02), (2.9, -0.1), (3.5, 0.5), (0.5, 2.0), (-1.0, 0.0)):
        assert grid[cell_of(x, y)] == UNKNOWN, (x, y)


def test_no_return_beams_free_space_up_to_no_return_free():
    ranges = np.full(181, np.inf)           # nothing returned anywhere
    grid = build_grid(scan_180(ranges), CFG)
    assert grid[cell_of(2.5, 0.0)] == FREE
    assert grid[cell_of(0.0, 2.5)] == FREE                      # +y, the last beam
    assert grid[cell_of(3.5, 0.0)] == UNKNOWN                   # beyond no_return_free
    assert not (grid == OCCUPIED).any()
    none_free = build_grid(scan_180(ranges), GridConfig(size=8.0, no_return_free=0.0))
    assert not (none_free == FREE).any()


def test_free_ranges_match_scan_semantics():
    """The grid's one-pass free ranges follow Scan.free_ranges: NaN, negative and below
    range_min free nothing, inf / >= range_max free up to no_return_free."""
    ranges = np.array([np.nan, -1.0, 0.01, 1.0, np.inf, 8.0, 2.5] * 20 + [1.0])
    scan = scan_180(ranges)
    frame = GridBuilder(CFG).build(scan)
    expected = scan.free_ranges(CFG.no_return_free)
    assert np.array_equal(frame.free, expected.astype(np.float32))


def test_free_erosion_bounds_a_beam_by_its_neighbours_on_one_surface_only():
    eroding = GridConfig(size=8.0, no_return_free=3.0, free_erosion=1, free_erosion_jump=0.5)
    ranges = np.full(181, 3.0)
    ranges[90] = 2.7                          # a step of 0.3 m: one (grazing) surface
    plain = build_grid(scan_180(ranges), CFG)
    eroded = build_grid(scan_180(ranges), eroding)
    # Beam 91's wedge at 2.85 m: free without erosion (3.0 > 2.85 + 0.1) but bounded by its
    # neighbour's 2.7 m with it.
    ij = cell_of(2.85, 0.01)                  # centre (2.85, 0.05): bearing 1 deg
    assert plain[ij] == FREE
    assert eroded[ij] == UNKNOWN
    assert eroded[cell_of(2.5, 1.0)] == FREE  # far from the step: unchanged
    # Across a depth jump (an object's edge, 2 m in front) beams are not bounded.
    ranges[90] = 1.0
    edge = build_grid(scan_180(ranges), eroding)
    assert edge[cell_of(2.85, 0.01)] == FREE


def test_beam_count_change_uses_a_new_ray_table():
    builder = GridBuilder(CFG)
    g1 = builder.build(scan_180(np.full(361, 2.0))).grid.copy()
    g2 = builder.build(scan_180(np.full(181, 2.0))).grid.copy()
    g3 = builder.build(scan_180(np.full(512, 2.0))).grid.copy()
    for g in (g1, g2, g3):
        assert g[cell_of(1.0, 0.0)] == FREE
        assert g[cell_of(0.0, 1.99)] == OCCUPIED or g[cell_of(0.0, 1.95)] == OCCUPIED
        assert g[cell_of(2.5, 0.0)] == UNKNOWN


def _ray_table_with_numpy(angle_min, angle_increment, n_beams, cells, resolution,
                          free_margin):
    """The ray table as whole-array numpy arithmetic (how the kernel must compute it)."""
    m = cells + 2 * PAD
    c = (np.arange(m) - PAD + 0.5 - cells / 2.0) * resolution
    cx, cy = np.meshgrid(c, c, indexing='ij')
    rng = np.hypot(cx, cy).ravel()
    bearing = np.arctan2(cy, cx).ravel()
    inc = float(angle_increment)
    delta = np.mod((bearing - angle_min) * math.copysign(1.0, inc), 2.0 * math.pi)
    k = delta / abs(inc)
    beam = np.rint(k)
    wrapped = np.rint(k - 2.0 * math.pi / abs(inc))
    use_wrapped = (beam > n_beams - 1) & (wrapped >= 0) & (wrapped <= n_beams - 1)
    beam = np.where(use_wrapped, wrapped, beam)
    beam = np.where((beam >= 0) & (beam <= n_beams - 1), beam, n_beams).astype(np.intp)
    reach = (rng + free_margin).astype(np.float32)
    border = np.ones((m, m), bool)
    border[PAD:-PAD, PAD:-PAD] = False
    beam[border.ravel()] = n_beams
    reach[border.ravel()] = np.inf
    return beam, reach


@pytest.mark.parametrize('angle_min, angle_increment, n_beams, cells, resolution, margin', [
    (float(np.float32(-math.pi / 2)), float(np.float32(math.pi / 360)), 361, 160, 0.1, 0.1),
    (-math.pi / 2, math.pi / 360, 361, 160, 0.1, 0.1),
    (-2.0862138271331787, 0.005759586766362190, 726, 160, 0.1, 0.1),     # Hokuyo-class
    (-math.pi, 2 * math.pi / 720, 720, 80, 0.1, 0.0),                    # all around
    (math.pi / 2, -math.pi / 180, 181, 100, 0.07, 0.2),                  # sweeping clockwise
    (0.3, 0.01, 50, 40, 0.25, 0.1),                                      # a narrow view
    (-3.0, 0.05, 200, 64, 0.1, 0.1),                                     # wrapping around
])
def test_the_ray_table_is_numpys_to_the_bit(angle_min, angle_increment, n_beams, cells,
                                            resolution, margin):
    """The kernel's ray table (cell bearings and reach made per grid, beams per scan
    geometry) equals the whole-array numpy arithmetic exactly."""
    table = ray_table(angle_min, angle_increment, n_beams, cells, resolution, margin)
    beam, reach = _ray_table_with_numpy(angle_min, angle_increment, n_beams, cells,
                                        resolution, margin)
    assert table.beam.dtype == beam.dtype and table.reach.dtype == reach.dtype
    assert np.array_equal(table.beam, beam)
    assert np.array_equal(table.reach, reach)
    assert table.n_beams == n_beams
    assert not table.beam.flags.writeable and not table.reach.flags.writeable


def test_full_circle_scanner_sees_behind():
    n = 360
    scan = Scan(stamp=0.0, ranges=np.full(n, 2.0), angle_min=-math.pi,
                angle_increment=2 * math.pi / n, range_min=0.05, range_max=8.0)
    grid = build_grid(scan, CFG)
    assert grid[cell_of(-1.0, 0.0)] == FREE
    assert grid[cell_of(-1.0, 0.05)] == FREE


def _grid_with(cells):
    g = np.full((N, N), UNKNOWN, np.uint8)
    for ij, v in cells.items():
        g[ij] = v
    return g


def test_transform_moves_a_known_cell_by_the_motion():
    previous = _grid_with({cell_of(2.05, 0.05): OCCUPIED})
    # The scanner moved 0.5 m forward: the obstacle is now 0.5 m closer.
    moved = transform_grid(previous, (0.5, 0.0, 0.0), RES)
    assert moved[cell_of(1.55, 0.05)] == OCCUPIED
    assert (moved == OCCUPIED).sum() == 1
    # The scanner turned 90 deg left: the obstacle ahead is now on its right (-y).
    turned = transform_grid(previous, (0.0, 0.0, math.pi / 2), RES)
    assert turned[cell_of(0.05, -2.05)] == OCCUPIED
    # Cells that come from outside the previous grid are unknown.
    free = np.full((N, N), FREE, np.uint8)
    shifted = transform_grid(free, (1.0, 0.0, 0.0), RES)
    assert (shifted[-10:, :] == UNKNOWN).all()
    assert (shifted[:-10, :] == FREE).all()


@pytest.mark.parametrize('motion', [(0.0, 0.0, 0.0), (0.23, -0.11, 0.0), (0.05, 0.3, 0.2),
                                    (-0.4, 0.17, -0.9), (1.3, 2.2, 3.0)])
def test_sparse_lookup_agrees_with_affine_transform(motion):
    rng = np.random.default_rng(3)
    previous = rng.integers(0, 3, size=(N, N)).astype(np.uint8)
    whole = transform_grid(previous, motion, RES)
    flat = rng.choice(N * N, 400, replace=False)
    ij = np.column_stack(np.divmod(flat, N)).astype(float)
    padded = np.pad(previous, PAD, constant_values=UNKNOWN)
    looked = lookup_grid(padded, motion, RES, ij)[:, 0]
    assert np.array_equal(looked, whole.reshape(-1)[flat])
    around = lookup_grid(padded, motion, RES, ij, neighbourhood=2)
    assert np.array_equal(around[:, 0], looked)
    # The neighbours: the cells next to the mapped cell in the previous grid.
    if motion == (0.0, 0.0, 0.0):
        for (i, j), row in zip(ij.astype(int), around):
            assert row.tolist() == [padded[i + PAD + di, j + PAD + dj]
                                    for di, dj in ((0, 0), (1, 0), (-1, 0), (0, 1), (0, -1),
                                                   (1, 1), (1, -1), (-1, 1), (-1, -1))]


def test_difference_map_equation_1():
    g = _grid_with({(1, 1): OCCUPIED, (1, 2): OCCUPIED, (1, 3): OCCUPIED, (1, 4): FREE,
                    (1, 5): UNKNOWN})
    gp = _grid_with({(1, 1): FREE, (1, 2): OCCUPIED, (1, 3): UNKNOWN, (1, 4): OCCUPIED,
                     (1, 5): FREE})
    d = difference_map(g, gp)
    # Only occupied-now-and-free-before is a change; unknown before is not; a cell that
    # became free (an object leaving) is not.
    assert d[1, 1] and not d[1, 2] and not d[1, 3] and not d[1, 4] and not d[1, 5]
    assert d.sum() == 1


def test_sparse_difference_equals_equation_1_on_whole_grids():
    """Detection's per-scan path (Eq. 1 at occupied cells only) equals Eq. 1 on grids."""
    rng = np.random.default_rng(7)
    builder = GridBuilder(CFG)
    r1 = 2.0 + rng.normal(0, 0.3, 181)
    r2 = r1.copy()
    r2[60:70] -= 0.8                            # something moved into free space
    f1 = builder.build(scan_180(r1))
    prev = f1.grid.copy()
    prev_padded = f1.padded.copy()
    motion = (0.07, -0.03, 0.02)
    f2 = builder.build(scan_180(r2, stamp=0.2))
    changed = changed_cells(f2.ij, prev_padded, motion, RES, DifferenceConfig())
    sparse = np.zeros(N * N, bool)
    sparse[f2.flat[changed]] = True
    whole = difference_map(f2.grid, transform_grid(prev, motion, RES)).reshape(-1)
    assert sparse.any()
    assert np.array_equal(sparse, whole)


def test_neighbourhood_tolerance_needs_free_neighbours():
    prev = _grid_with({(10, 10): FREE, (11, 10): FREE, (9, 10): FREE, (10, 11): FREE,
                       (10, 9): OCCUPIED, (20, 20): FREE, (21, 20): FREE, (19, 20): FREE,
                       (20, 21): FREE, (20, 19): FREE})
    padded = np.pad(prev, PAD, constant_values=UNKNOWN)
    ij = np.array([[10.0, 10.0], [20.0, 20.0]])
    paper = changed_cells(ij, padded, (0, 0, 0), RES, DifferenceConfig(free_neighbourhood=0))
    tolerant = changed_cells(ij, padded, (0, 0, 0), RES,
                             DifferenceConfig(free_neighbourhood=1))
    assert paper.tolist() == [True, True]
    assert tolerant.tolist() == [False, True]


def test_no_return_free_bounds_only_beams_that_returned_nothing():
    ranges = np.full(181, 3.0)
    ranges[:40] = np.inf                    # no return on the right side
    for limit in (0.0, 1.0):
        grid = build_grid(scan_180(ranges), GridConfig(size=8.0, no_return_free=limit,
                                                       free_erosion=0))
        assert grid[cell_of(2.5, 0.0)] == FREE          # a return frees up to the hit
        assert grid[cell_of(0.0, -1.5)] == (FREE if limit > 1.5 else UNKNOWN)
    grid = build_grid(scan_180(ranges), GridConfig(size=8.0, no_return_free=0.0,
                                                   free_erosion=0))
    assert grid[cell_of(0.0, -0.5)] == UNKNOWN          # 0: a no-return beam frees nothing


def test_free_depth_is_how_far_the_covering_beam_continued():
    ranges = np.full(181, 3.0)
    ranges[90] = 2.0                        # straight ahead the beam stops at 2 m
    frame = GridBuilder(CFG).build(scan_180(ranges))
    depth = frame.free_depth(np.array([[1.0, 0.0], [2.5, 0.0], [0.0, 1.0], [-1.0, 0.0]]))
    assert depth[0] == pytest.approx(1.0, abs=1e-5)
    assert depth[1] == pytest.approx(-0.5, abs=1e-5)    # beyond the hit: not seen free
    assert depth[2] == pytest.approx(2.0, abs=1e-5)     # the +y beam
    assert depth[3] == -np.inf                          # behind the scanner


def test_deep_free_asks_for_free_space_beyond_the_motion_displacement():
    from laser_tracker.core.difference import deep_free
    previous = GridBuilder(CFG).build(scan_180(np.full(181, 3.0)))   # a wall all round at 3 m
    motion = (0.4, 0.0, 0.0)                # the scanner moved 0.4 m forward since
    near_wall = np.array([cell_of(2.35, 0.05)], float)   # 2.75 m from the old position
    open_space = np.array([cell_of(1.05, 0.05)], float)
    for depth, near_ok in ((0.0, True), (0.5, True), (1.0, False)):
        cfg = DifferenceConfig(motion_depth=depth)
        # 0.5 x 0.4 m = 0.2 m < 0.25 m of free space behind the cell; 1 x 0.4 m is not.
        assert deep_free(near_wall, previous, motion, RES, N, cfg)[0] == near_ok, depth
        assert deep_free(open_space, previous, motion, RES, N, cfg)[0]
    # A turn adds range x |rotation|: 0.5 x (0 + 2.75 m x 0.4 rad) = 0.55 m of free space
    # wanted, about 0.25 m there; in open space 0.5 x 1.05 m x 0.4 rad = 0.21 m < 1.95 m.
    cfg = DifferenceConfig(motion_depth=0.5)
    for r, ok in ((2.75, False), (1.05, True)):
        turned = np.array([cell_of(r * math.cos(-0.4), r * math.sin(-0.4))], float)
        assert deep_free(turned, previous, (0.0, 0.0, 0.4), RES, N, cfg)[0] == ok, r
    # A stationary scanner needs nothing beyond FREE.
    assert deep_free(np.array([cell_of(2.85, 0.05)], float), previous, (0.0, 0.0, 0.0),
                     RES, N, cfg)[0]


# ----------------------------------------------------------- beams without a return


BOUNDED = GridConfig(resolution=RES, size=8.0, free_margin=0.1, no_return_free=3.0,
                     free_erosion=0, no_return_bounds=True, grazing_incidence=60.0,
                     lost_echoes=0.0)


def _ray(angle, r):
    return r * math.cos(angle), r * math.sin(angle)


def test_a_gap_in_a_wall_frees_space_only_up_to_the_wall():
    """Beams that lost their echo on a dark patch of a wall (2 m ahead, facing the scanner)
    free space up to the wall, not through it; the paper's rule frees 3 m straight on."""
    n = 181
    angles = np.linspace(-math.pi / 2, math.pi / 2, n)
    ranges = 2.0 / np.maximum(np.cos(angles), 1e-3)      # the wall x = 2
    ranges[ranges > 2.9] = np.inf                        # beyond: nothing
    ranges[85:96] = np.inf                               # the dark patch
    behind = cell_of(2.5, 0.05)
    assert build_grid(scan_180(ranges), CFG)[behind] == FREE
    bounded = build_grid(scan_180(ranges), BOUNDED)
    assert bounded[behind] == UNKNOWN
    assert bounded[cell_of(2.0, 0.05)] != FREE           # the wall's cells
    assert bounded[cell_of(1.5, 0.05)] == FREE           # in front of it: seen free


def test_a_grazing_wall_frees_no_space_along_its_continuation():
    """A wall 0.6 m to the left, returns lost beyond 70 deg of incidence (1.6 m ahead): the
    beams past its visible end may have hit it, so its continuation is not freed (it would
    be 'free before, occupied now' as the robot advances); open space away from it is."""
    n = 361
    angles = np.linspace(-math.pi / 2, math.pi / 2, n)
    ranges = np.full(n, np.inf)
    left = angles > 0.05
    wall = 0.6 / np.sin(np.where(left, angles, 1.0))
    incidence = np.pi / 2 - angles
    seen = left & (incidence < math.radians(70))
    ranges[seen] = wall[seen]
    ranges[(angles > -0.1) & (angles < 0.05)] = 2.5      # something far ahead, not a wall
    continuation = cell_of(2.4, 0.65)                    # on the wall, beyond its visible end
    assert build_grid(scan_180(ranges), CFG)[continuation] == FREE
    bounded = build_grid(scan_180(ranges), BOUNDED)
    assert bounded[continuation] == UNKNOWN
    assert bounded[cell_of(1.2, 0.3)] == FREE            # the corridor in front of the wall
    assert bounded[cell_of(1.5, -1.5)] == FREE           # open space on the right
    # The wall's continuation beyond the chord to the next return is not freed either.
    ranges[(angles > -0.1) & (angles < 0.05)] = np.inf
    assert build_grid(scan_180(ranges), BOUNDED)[continuation] == UNKNOWN


def test_open_space_and_a_facing_edge_still_free_space():
    """A person walking into open space must still be seen walking in: where the neighbours
    return nothing, or the only surface is a small object facing the scanner, beams without
    a return free space as before, right up to the object's edge."""
    ranges = np.full(181, np.inf)
    ranges[89:92] = 1.5                                  # a leg, facing the scanner
    bounded = build_grid(scan_180(ranges), BOUNDED)
    for x, y in ((2.5, 0.8), (2.5, -0.8), (1.0, 2.0), (0.5, -2.5), (2.0, 0.12)):
        assert bounded[cell_of(x, y)] == FREE, (x, y)


def test_the_end_of_a_facing_wall_bounds_only_for_a_scanner_that_loses_echoes():
    """A wall 2 m ahead, facing the scanner, whose returns end 0.5 m to the left: for a
    scanner that loses echoes on surfaces in range (a dark wall fades with range), the beams
    past the end may have hit the wall, so its continuation bounds them; for one that
    returns from every surface, the end is the wall's end (a doorway) and they free space."""
    n = 181
    angles = np.linspace(-math.pi / 2, math.pi / 2, n)
    ranges = np.full(n, np.inf)
    seen = (angles > -0.46) & (angles < 0.245)
    ranges[seen] = 2.0 / np.cos(angles[seen])            # the wall x = 2, y -1 .. 0.5
    past_the_end = cell_of(2.4, 0.8)
    loses = build_grid(scan_180(ranges), BOUNDED)        # lost_echoes 0: it does
    assert loses[past_the_end] == UNKNOWN
    assert loses[cell_of(1.5, 0.6)] == FREE              # in front of the continuation
    keeps = GridBuilder(dataclasses.replace(BOUNDED, lost_echoes=0.5))
    assert keeps.build(scan_180(ranges)).grid[past_the_end] == FREE


def test_a_lost_echo_frees_only_lost_echo_free_on_a_scanner_that_loses_echoes():
    """A wall 2 m ahead whose middle returns nothing (a dark patch): on a scanner that loses
    echoes, lost_echo_free bounds what the silent beams free (here to 1 m, short of the
    wall's chord), and a scanner that does not lose echoes frees no_return_free as before."""
    n = 181
    angles = np.linspace(-math.pi / 2, math.pi / 2, n)
    ranges = 2.0 / np.maximum(np.cos(angles), 1e-3)
    ranges[ranges > 2.9] = np.inf
    ranges[85:96] = np.inf
    near, far = cell_of(0.5, 0.0), cell_of(1.5, 0.0)
    default = GridBuilder(dataclasses.replace(BOUNDED, lost_echoes=0.0))
    grid = default.build(scan_180(ranges)).grid
    assert grid[near] == FREE and grid[far] == FREE      # up to the chord at 2 m
    bounded = GridBuilder(dataclasses.replace(BOUNDED, lost_echoes=0.0, lost_echo_free=1.0))
    grid = bounded.build(scan_180(ranges)).grid
    assert grid[near] == FREE and grid[far] == UNKNOWN
    sees_all = GridBuilder(dataclasses.replace(BOUNDED, lost_echoes=1.0, lost_echo_free=1.0))
    assert sees_all.build(scan_180(ranges)).grid[far] == FREE


def test_gaps_are_bridged_only_for_a_scanner_that_loses_echoes():
    """A scanner that returns from every surface in range sees through a gap in a wall into
    free space; a scanner that keeps losing echoes between nearby returns (here 6 % of its
    beams, scan after scan) may have lost a surface in the gap."""
    n = 181
    angles = np.linspace(-math.pi / 2, math.pi / 2, n)
    ranges = 2.0 / np.maximum(np.cos(angles), 1e-3)
    ranges[ranges > 2.9] = np.inf
    ranges[85:96] = np.inf                               # 11 of 181 beams: 6 %
    behind = cell_of(2.5, 0.05)
    config = dataclasses.replace(BOUNDED, lost_echoes=0.05)
    builder = GridBuilder(config)
    for _ in range(40):
        grid = builder.build(scan_180(ranges)).grid
    assert grid[behind] == UNKNOWN
    whole = 2.0 / np.maximum(np.cos(angles), 1e-3)
    whole[whole > 2.9] = np.inf
    for _ in range(400):                                 # the wall whole again: it forgets
        builder.build(scan_180(whole))
    assert builder.build(scan_180(ranges)).grid[behind] == FREE


@pytest.mark.parametrize('angle_min, angle_increment, n_beams, cells, resolution', [
    (-math.pi / 2, math.pi / 360, 361, 160, 0.1),                        # SICK LMS
    (-2.0862138271331787, 0.005759586766362190, 726, 160, 0.1),          # Hokuyo-class
    (math.pi / 2, -math.pi / 180, 181, 100, 0.07),                       # sweeping clockwise
])
def test_the_footprint_of_a_cell_is_every_beam_within_its_angular_extent(
        angle_min, angle_increment, n_beams, cells, resolution):
    """The ray table's first and last beam of each cell are those whose direction lies
    within half the angle the cell subtends on either side of its centre's bearing (the
    cell's own beam at least); without footprints, the cell's own beam alone."""
    table = ray_table(angle_min, angle_increment, n_beams, cells, resolution, 0.1, True)
    plain = ray_table(angle_min, angle_increment, n_beams, cells, resolution, 0.1)
    assert np.array_equal(plain.rays[1], plain.beam) and np.array_equal(plain.rays[2], plain.beam)
    assert np.array_equal(table.rays[0], table.beam)
    m = cells + 2 * PAD
    half = resolution / 2
    rng = np.random.default_rng(0)
    cells_with_a_beam = np.flatnonzero(table.beam < n_beams)
    directions = angle_min + np.arange(n_beams) * angle_increment
    widths = []
    for p in rng.choice(cells_with_a_beam, 400, replace=False):
        x = (p // m - PAD + 0.5 - cells / 2) * resolution
        y = (p % m - PAD + 0.5 - cells / 2) * resolution
        if abs(x) <= half and abs(y) <= half:
            continue
        centre = math.atan2(y, x)
        span = max(abs(math.remainder(math.atan2(y + dy, x + dx) - centre, 2 * math.pi))
                   for dx in (-half, half) for dy in (-half, half))
        apart = np.abs(np.remainder(directions - centre + math.pi, 2 * math.pi) - math.pi)
        b = table.beam[p]
        for inside in (np.flatnonzero(apart <= span - 1e-9),   # a beam through a corner
                       np.flatnonzero(apart <= span + 1e-9)):  # may go either way
            low, high = min(inside.min(initial=b), b), max(inside.max(initial=b), b)
            if table.rays[1, p] == low and table.rays[2, p] == high:
                break
        else:
            raise AssertionError(f'cell {p}: beams {table.rays[1:, p]}, not {low}-{high}')
        widths.append(table.rays[2, p] - table.rays[1, p])
    assert max(widths) > 2                              # near cells span several beams


def test_a_return_just_inside_the_grids_edge_gets_no_cell_outside_it():
    """x just below half the grid's side rounds onto the edge cell index (cells): such a
    return is left out, never given a flat index past the grid (kernels index by it)."""
    builder = GridBuilder(GridConfig())
    half = builder.cells * builder.config.resolution / 2.0
    edge = np.nextafter(half, 0.0)
    ranges = np.array([edge, edge, 3.0])
    scan = Scan(stamp=0.0, ranges=ranges, angle_min=0.0, angle_increment=math.pi / 2,
                range_min=0.05, range_max=20.0)
    frame = builder.build(scan)
    assert frame.flat.size >= 1                                   # the 3 m return
    assert (frame.flat < builder.cells ** 2).all() and (frame.ij < builder.cells).all()
