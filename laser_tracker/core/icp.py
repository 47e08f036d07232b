"""Point-to-line ICP for 2D scans against a short local map, as compiled kernels.

The pieces used by :mod:`laser_tracker.core.egomotion`:

* :func:`match_scan`: the points a scan gives the matcher (valid beams within the range
  limits, evenly thinned) and, when a match is wanted, :func:`align`'s result for them: one
  kernel call per scan.
* :class:`LocalMap`: the last few key scans' points and normals in the odometry (world)
  frame with a grid hash for nearest neighbours; both change only when a key scan joins
  (:meth:`LocalMap.add_scan`: normals, placement and the grid in one kernel call).
* :func:`scan_normals`: a unit normal per scan point from its two neighbours along the scan
  (central difference, one-sided at a segment end, none for an isolated point); a range jump
  larger than ``max_gap + gap_ratio * range`` ends a segment.
* :func:`align`: robust (Cauchy) point-to-line Gauss-Newton on SE(2) with coarse-to-fine
  association distances; returns an :class:`IcpResult` with the Hessian and its
  normalised eigen-decomposition (degeneracy). Acceptance and the odometry prior are the
  caller's (``egomotion``).

Nearest neighbours (:func:`nearest`): map points are hashed by grid cell (``CELL`` m); a
query visits rings of cells around its own, skipping cells farther than the nearest point
found, until no unvisited cell can hold a nearer point within the association distance. The
answer is the nearest map point strictly within the distance; when several are exactly as
near (quantised ranges make that common) it is the one scipy's cKDTree would return: a
KD-tree built as cKDTree builds it (leafsize 16, sliding midpoint) answers those queries.
So associations, and with the sums added in numpy's order (``jit``), poses are bit for bit
those of the numpy formulation with cKDTree.

Poses are ``(x, y, theta)`` of the scanner in the world frame; a correction ``delta`` is
applied on the right (``pose (+) delta``), i.e. it is expressed in the scanner frame, and the
Hessian is for that parametrisation.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from laser_tracker.core import jit
from laser_tracker.core.jit import blas_dot, einsum_dot, fma, pairwise_sum

#: Grid-hash cell size (m): speed only, the neighbours found do not depend on it.
CELL = 0.2
#: Slack (m) in the ring bounds of the neighbour search, far above rounding errors.
_SLACK = 1e-7
#: Settings layout for the kernels (a float array, one argument instead of many).
_KERNEL_RATIO, _STEPS, _TOL_T, _TOL_R, _DAMPING, _CONV_T, _CONV_R, _STRIDE, _N_COARSE = \
    range(9)
#: Columns of a map row after the world point (x, y): world normal, normal . point.
_NX, _NY, _NQ = 2, 3, 4
#: Grid description layout: origin, 1 / cell, cell, cells along x and y, hash mask.
_OX, _OY, _INV, _SIZE, _NCX, _NCY, _MASK = range(7)
#: A local map's state (int64): its rows, its scans, the most scans it keeps, and from
#: ``_SIZES`` on each scan's rows, oldest first.
_ROWS, _SCANS, _MOST, _SIZES = range(4)


# ------------------------------------------------------------------------------ kernels


@jit.kernel
def _normals(points, max_gap, gap_ratio):
    m = points.shape[0]
    normals = np.zeros((m, 2))
    ok = np.zeros(m, dtype=np.bool_)
    if m < 2:
        return normals, ok
    # squared ranges (hypot decides only where they leave the link test open: _linked)
    rng2 = np.empty(m)
    for i in range(m):
        rng2[i] = points[i, 0] * points[i, 0] + points[i, 1] * points[i, 1]
    tx = np.zeros(m)
    ty = np.zeros(m)
    for i in range(m - 1):
        dx = points[i + 1, 0] - points[i, 0]
        dy = points[i + 1, 1] - points[i, 1]
        if _linked(points[i, 0], points[i, 1], points[i + 1, 0], points[i + 1, 1], dx, dy,
                   math.sqrt(min(rng2[i + 1], rng2[i])), max_gap, gap_ratio):
            tx[i] += dx       # forward difference where linked
            ty[i] += dy
            tx[i + 1] += dx   # backward difference where linked
            ty[i + 1] += dy
    for i in range(m):
        norm = math.hypot(tx[i], ty[i])
        if norm > 1e-9:
            ok[i] = True
            nx = -ty[i] * (1.0 / norm)
            ny = tx[i] * (1.0 / norm)
            if nx * points[i, 0] + ny * points[i, 1] > 0.0:   # face the scanner
                nx, ny = -nx, -ny
            normals[i, 0] = nx
            normals[i, 1] = ny
    return normals, ok


@jit.inline
def _linked(x0, y0, x1, y1, dx, dy, near, max_gap, gap_ratio):
    """``hypot(dx, dy) < max_gap + gap_ratio * min(hypot(x1, y1), hypot(x0, y0))``: the link
    test of :func:`_normals` between consecutive points ``(x0, y0)`` and ``(x1, y1)``.
    Square roots of the squared lengths (``near``: of the nearer point's range) decide
    unless they are within a relative 1e-9 of the limit (far above their rounding errors
    and hypot's), where hypot does: it costs more. (Coordinates, not the points' array: an
    array read in one branch only would cost reference counting per call.)"""
    limit = max_gap + gap_ratio * near
    if max_gap >= 0.0 and 0.0 <= gap_ratio <= 1e6 and 1e-100 < limit < 1e100 and \
            abs(dx) < 1e100 and abs(dy) < 1e100:        # no overflow, nothing lost below
        length = math.sqrt(dx * dx + dy * dy)
        if length < limit * (1.0 - 1e-9):
            return True
        if length > limit * (1.0 + 1e-9):
            return False
    return math.hypot(dx, dy) < max_gap + gap_ratio * min(math.hypot(x1, y1),
                                                          math.hypot(x0, y0))


@jit.kernel
def _add_scan(points, pose, max_gap, gap_ratio, cell, rows, grid_xy, order, start, grid,
              state):
    """In place on a local map's buffers (:meth:`LocalMap.buffers`; ``state``: rows, scans,
    most scans, each scan's rows oldest first): the world rows (x, y, nx, ny, n.q) of
    ``points`` seen from ``pose`` that have a normal join the map (the oldest scan leaves when
    there are ``state[2]`` scans), and the grid hash is rebuilt; none with a normal: the map
    stays as it is. Returns the rows added. The buffers hold the map's rows and these."""
    normals, ok = _normals(points, max_gap, gap_ratio)
    added = 0
    for i in range(points.shape[0]):
        added += ok[i]
    if added == 0:
        return 0
    n_rows, n_scans = state[_ROWS], state[_SCANS]
    keep_from = 0
    if n_scans == state[_MOST]:               # the oldest scan leaves
        keep_from = state[_SIZES]
        for k in range(n_scans - 1):
            state[_SIZES + k] = state[_SIZES + k + 1]
        n_scans -= 1
    n_old = n_rows - keep_from
    if n_old + added > rows.shape[0]:
        raise ValueError('local map buffers too small (LocalMap.reserve)')
    for i in range(n_old):
        for c in range(5):
            rows[i, c] = rows[keep_from + i, c]
    c, s = math.cos(pose[2]), math.sin(pose[2])
    k = n_old
    for i in range(points.shape[0]):
        if ok[i]:
            px, py = points[i, 0], points[i, 1]
            nx, ny = normals[i, 0], normals[i, 1]
            qx = fma(py, -s, px * c) + pose[0]
            qy = fma(py, c, px * s) + pose[1]
            wx = fma(ny, -s, nx * c)
            wy = fma(ny, c, nx * s)
            rows[k, 0], rows[k, 1], rows[k, 2], rows[k, 3] = qx, qy, wx, wy
            rows[k, 4] = wx * qx + wy * qy
            k += 1
    state[_SIZES + n_scans] = added
    state[_SCANS] = n_scans + 1
    state[_ROWS] = k
    _grid_hash(rows, k, cell, grid_xy, order, start, grid)
    return added


@jit.inline
def _hash_size(n):
    """Buckets of the grid hash of ``n`` rows: a power of two, at least 16 and 2 n."""
    size = 16
    while size < 2 * n:
        size *= 2
    return size


@jit.kernel
def _grid_hash(rows, n, cell, grid_xy, order, start, grid):
    """The grid hash of ``rows[:n]``, into the buffers: the points (x, y) sorted by hash
    bucket of their grid cell (``grid_xy[:n]``: what the neighbour search reads, compact),
    their indices in ``rows`` (``order[:n]``), the buckets' starts (``start[:size + 1]``),
    and the grid (origin, 1 / cell, cell, cells along x and y, hash mask)."""
    grid[:] = 0.0
    if n == 0:
        start[0] = start[1] = 0
        return
    ox, oy = rows[0, 0], rows[0, 1]
    hx, hy = ox, oy
    for i in range(n):
        ox = min(ox, rows[i, 0])
        oy = min(oy, rows[i, 1])
        hx = max(hx, rows[i, 0])
        hy = max(hy, rows[i, 1])
    inv = 1.0 / cell
    size = _hash_size(n)
    grid[_OX], grid[_OY], grid[_INV], grid[_SIZE] = ox, oy, inv, cell
    grid[_NCX] = int((hx - ox) * inv) + 1
    grid[_NCY] = int((hy - oy) * inv) + 1
    grid[_MASK] = size - 1
    bucket = np.empty(n, np.int64)
    start[:size + 1] = 0
    for i in range(n):
        b = _bucket(int((rows[i, 0] - ox) * inv), int((rows[i, 1] - oy) * inv), size - 1)
        bucket[i] = b
        start[b + 1] += 1
    for b in range(size):
        start[b + 1] += start[b]
    fill = start[:size].copy()
    for i in range(n):
        k = fill[bucket[i]]
        fill[bucket[i]] += 1
        order[k] = i
        grid_xy[k, 0], grid_xy[k, 1] = rows[i, 0], rows[i, 1]


@jit.kernel
def _bucket(ix, iy, mask):
    return ((ix * 73856093) ^ (iy * 19349663)) & mask


@jit.kernel
def _nearest(qx, qy, d, rows, start, grid):
    """``(j, tied)``: the row in ``rows`` (points x, y in grid order) of the point nearest
    to (qx, qy) strictly within ``d`` (-1: none), and whether another is exactly as near."""
    ox, oy, inv, cell = grid[_OX], grid[_OY], grid[_INV], grid[_SIZE]
    ncx, ncy, mask = int(grid[_NCX]), int(grid[_NCY]), int(grid[_MASK])
    fx = (qx - ox) * inv
    fy = (qy - oy) * inv
    if fx < -d * inv - 1.0 or fy < -d * inv - 1.0 or fx > ncx + d * inv + 1.0 \
            or fy > ncy + d * inv + 1.0:
        return -1, False               # farther than d from every map point
    cx = int(math.floor(fx))
    cy = int(math.floor(fy))
    # the query's distance to its own cell's nearest side (cells)
    edge = min(fx - cx, cx + 1.0 - fx, fy - cy, cy + 1.0 - fy)
    best = -1
    best_d2 = d * d
    tied = False
    k = 0
    while True:
        for ix in range(max(cx - k, 0), min(cx + k, ncx - 1) + 1):
            if ix == cx - k or ix == cx + k:         # a side of the ring: every cell
                lo, hi, step = max(cy - k, 0), min(cy + k, ncy - 1), 1
            else:                                    # inside: the ring's two ends
                lo, hi, step = cy - k, cy + k, 2 * k
            gx = max(ix - fx, fx - ix - 1.0, 0.0) * cell - _SLACK
            gx = max(gx, 0.0)
            for iy in range(lo, hi + 1, step):
                if iy < 0 or iy >= ncy:
                    continue
                gy = max(max(iy - fy, fy - iy - 1.0, 0.0) * cell - _SLACK, 0.0)
                if gx * gx + gy * gy > best_d2:      # the whole cell is farther
                    continue
                b = _bucket(ix, iy, mask)
                for j in range(start[b], start[b + 1]):
                    dx = rows[j, 0] - qx
                    dy = rows[j, 1] - qy
                    d2 = 0.0 + dx * dx
                    d2 += dy * dy
                    if d2 < best_d2:
                        best, best_d2, tied = j, d2, False
                    elif d2 == best_d2 and best >= 0 and j != best:
                        tied = True
        # every point not visited yet is at least this far
        reach = (k + edge) * cell - _SLACK
        if reach > 0.0 and (reach >= d or best_d2 < reach * reach):
            return best, tied
        k += 1


# The KD-tree's answer on ties. When two map points are exactly as near (it happens: ranges
# are quantised), the nearest neighbour is the one scipy's cKDTree (leafsize 16, sliding
# midpoint, compact_nodes=False, balanced_tree=False) finds first. Such a tree is built on
# the first tie of a match and answers the tied queries, exactly as cKDTree does.

_LEAF_SIZE = 16


@jit.kernel
def _partition(idx, lo, hi, pts, dim, pivot):
    """C++ ``std::partition`` (libstdc++, bidirectional) of ``idx[lo:hi]`` by
    ``pts[i, dim] < pivot``; returns the partition point."""
    first, last = lo, hi
    while True:
        while True:
            if first == last:
                return first
            if pts[idx[first], dim] < pivot:
                first += 1
            else:
                break
        last -= 1
        while True:
            if first == last:
                return first
            if not pts[idx[last], dim] < pivot:
                last -= 1
            else:
                break
        idx[first], idx[last] = idx[last], idx[first]
        first += 1


@jit.kernel
def _split(idx, lo, hi, pts, mins, maxes):
    """``(dim, split, partition point)`` of a node (sliding midpoint), or dim -1: a leaf."""
    mins, maxes = mins.copy(), maxes.copy()
    while True:
        dim, size = 0, 0.0
        for i in range(2):
            if maxes[i] - mins[i] > size:
                dim, size = i, maxes[i] - mins[i]
        if maxes[dim] == mins[dim]:
            return -1, 0.0, -1
        split = (maxes[dim] + mins[dim]) / 2
        p = _partition(idx, lo, hi, pts, dim, split)
        if p == lo:            # nothing below: slide up to the smallest value
            low = pts[idx[lo], dim]
            for i in range(lo + 1, hi):
                low = min(low, pts[idx[i], dim])
            split = np.nextafter(low, np.inf)
            p = _partition(idx, lo, hi, pts, dim, split)
        elif p == hi:          # nothing above: slide down to the largest value
            high = pts[idx[lo], dim]
            for i in range(lo + 1, hi):
                high = max(high, pts[idx[i], dim])
            split = high
            p = _partition(idx, lo, hi, pts, dim, split)
        if p == lo or p == hi:  # all equal along dim: try the other dimension
            mins[dim] = maxes[dim] = pts[idx[lo], dim]
            continue
        return dim, split, p


@jit.kernel
def _kdtree(pts):
    """cKDTree's nodes for ``pts`` (N, 2): (indices, int table [dim, start, end, less,
    greater] per node, splits, the points' box: min x, min y, max x, max y)."""
    n = pts.shape[0]
    idx = np.arange(n)
    cap = 2 * n + 1
    table = np.zeros((cap, 5), np.int64)
    splits = np.zeros(cap)
    boxes = np.zeros((cap, 4))                  # mins x, y, maxes x, y of a node to build
    stack = np.zeros(cap, np.int64)
    count = 1
    table[0, 0], table[0, 1], table[0, 2] = -1, 0, n
    for dim in range(2):
        boxes[0, dim] = pts[:, dim].min()
        boxes[0, 2 + dim] = pts[:, dim].max()
    top = 1                                     # stack[0] = the root
    while top:
        top -= 1
        node = stack[top]
        lo, hi = table[node, 1], table[node, 2]
        if hi - lo <= _LEAF_SIZE:
            continue
        dim, split, p = _split(idx, lo, hi, pts, boxes[node, :2], boxes[node, 2:])
        if dim < 0:
            continue
        less, greater = count, count + 1
        count += 2
        table[node, 0], table[node, 3], table[node, 4] = dim, less, greater
        splits[node] = split
        table[less, 0], table[less, 1], table[less, 2] = -1, lo, p
        table[greater, 0], table[greater, 1], table[greater, 2] = -1, p, hi
        boxes[less] = boxes[node]
        boxes[less, 2 + dim] = split
        boxes[greater] = boxes[node]
        boxes[greater, dim] = split
        stack[top] = greater
        stack[top + 1] = less
        top += 2
    return idx, table[:count].copy(), splits[:count].copy(), boxes[0].copy()


@jit.kernel
def _kdtree_nearest(qx, qy, d, pts, idx, table, splits, box, heap_prio, heap_info):
    """cKDTree's ``query(q, k=1, distance_upper_bound=d)``: the index into ``pts`` or -1.
    ``heap_*``: scratch space (one row per node)."""
    bound = d * d
    q = (qx, qy)
    side0 = side1 = 0.0
    lo0, lo1, hi0, hi1 = box[0], box[1], box[2], box[3]
    s = 0.0
    if qx - hi0 > s:
        s = qx - hi0
    elif lo0 - qx > s:
        s = lo0 - qx
    min_d = 0.0 + (s * s - side0)
    side0 = s * s
    s = 0.0
    if qy - hi1 > s:
        s = qy - hi1
    elif lo1 - qy > s:
        s = lo1 - qy
    min_d += s * s - side1
    side1 = s * s
    node = 0
    best = -1
    n_heap = 0
    while True:
        if table[node, 0] < 0:                      # leaf: every point, in tree order
            for i in range(table[node, 1], table[node, 2]):
                k = idx[i]
                d0 = pts[k, 0] - qx
                d1 = pts[k, 1] - qy
                dd = 0.0 + d0 * d0
                dd += d1 * d1
                if dd < bound:
                    best, bound = k, dd
            if n_heap == 0:
                return best
            node = int(heap_info[0, 0])             # pop the nearest cell
            min_d, side0, side1 = heap_prio[0], heap_info[0, 1], heap_info[0, 2]
            n_heap = _heap_remove(heap_prio, heap_info, n_heap)
            continue
        if min_d > bound:
            return best
        dim = table[node, 0]
        split = splits[node]
        if q[dim] < split:
            near, far, gap = table[node, 3], table[node, 4], split - q[dim]
        else:
            near, far, gap = table[node, 4], table[node, 3], q[dim] - split
        far_side0, far_side1 = side0, side1
        far_min = min_d
        if dim == 0:
            far_min += gap * gap - far_side0
            far_side0 = gap * gap
        else:
            far_min += gap * gap - far_side1
            far_side1 = gap * gap
        node = near
        if min_d > far_min:
            node, far = far, node
            min_d, far_min = far_min, min_d
            side0, far_side0 = far_side0, side0
            side1, far_side1 = far_side1, side1
        if far_min <= bound:
            n_heap = _heap_push(heap_prio, heap_info, n_heap, far_min, far, far_side0,
                                far_side1)


@jit.kernel
def _heap_push(prio, info, n, priority, node, side0, side1):
    """cKDTree's priority queue: push (sifting up while strictly smaller)."""
    i = n
    prio[i] = priority
    info[i, 0], info[i, 1], info[i, 2] = node, side0, side1
    while i > 0 and prio[i] < prio[(i - 1) // 2]:
        parent = (i - 1) // 2
        _heap_swap(prio, info, i, parent)
        i = parent
    return n + 1


@jit.kernel
def _heap_remove(prio, info, n):
    """cKDTree's priority queue: remove the top (the last item sifts down)."""
    prio[0] = prio[n - 1]
    info[0] = info[n - 1]
    n -= 1
    i, j, k = 0, 1, 2
    while (j < n and prio[i] > prio[j]) or (k < n and prio[i] > prio[k]):
        child = k if k < n and prio[j] > prio[k] else j
        _heap_swap(prio, info, i, child)
        i = child
        j, k = 2 * i + 1, 2 * i + 2
    return n


@jit.kernel
def _heap_swap(prio, info, a, b):
    prio[a], prio[b] = prio[b], prio[a]
    for c in range(3):
        info[a, c], info[b, c] = info[b, c], info[a, c]


@jit.kernel
def _no_tree():
    return (np.zeros(0, np.int64), np.zeros((0, 5), np.int64), np.zeros(0), np.zeros(4),
            np.zeros(0), np.zeros((0, 3)), np.zeros((0, 2)))


@jit.kernel
def _tie(qx, qy, d, rows, tree):
    """``(k, tree)``: the index in ``rows`` of the point cKDTree answers for (qx, qy) when
    several are exactly as near; ``tree`` (:func:`_no_tree` at first) is built on the first
    tie."""
    idx, table, splits, box, heap_prio, heap_info, points = tree
    if table.shape[0] == 0:
        points = np.ascontiguousarray(rows[:, :2])
        idx, table, splits, box = _kdtree(points)
        heap_prio, heap_info = np.zeros(table.shape[0]), np.zeros((table.shape[0], 3))
    k = _kdtree_nearest(qx, qy, d, points, idx, table, splits, box, heap_prio, heap_info)
    return k, (idx, table, splits, box, heap_prio, heap_info, points)


@jit.inline
def _associate(a, matched, n, rows, k, px, py):
    """Association row ``n``: the scan point (px, py) with map point ``k`` (a row of
    ``rows``): u = n.p, v = n x p, nx, ny, n.q."""
    nx, ny, nq = rows[k, _NX], rows[k, _NY], rows[k, _NQ]
    a[n, 0] = nx * px + ny * py
    a[n, 1] = nx * -py + ny * px
    a[n, 2], a[n, 3], a[n, 4] = nx, ny, nq
    matched[n, 0], matched[n, 1] = px, py


@jit.kernel
def _untie(a, matched, tied, n_tied, c, s, x, y, d, rows, tree):
    """Association rows ``tied[:n_tied]`` (their nearest map point is tied) with the
    point cKDTree answers, the query placed as :func:`_align` placed it; returns the tree
    (:func:`_tie`)."""
    for t in range(n_tied):
        n = tied[t]
        px, py = matched[n, 0], matched[n, 1]
        qx, qy = fma(py, -s, px * c) + x, fma(py, c, px * s) + y
        k, tree = _tie(qx, qy, d, rows, tree)
        _associate(a, matched, n, rows, k, px, py)
    return tree


@jit.kernel
def _nearest_all(queries, d, rows, grid_xy, order, start, grid):
    out = np.full(queries.shape[0], -1, np.int64)
    tree = _no_tree()
    for i in range(queries.shape[0]):
        j, tied = _nearest(queries[i, 0], queries[i, 1], d, grid_xy, start, grid)
        if j >= 0:
            out[i] = order[j]
            if tied:
                out[i], tree = _tie(queries[i, 0], queries[i, 1], d, rows, tree)
    return out


@jit.kernel
def _solve3(h, g0, g1, g2, damping):
    """``-(H + damping * trace(H) * I)^-1 g`` for a symmetric 3x3 H (Cramer's rule);
    ``ok`` False when singular."""
    lam = damping * (h[0, 0] + h[1, 1] + h[2, 2]) + 1e-12
    a, b, c = h[0, 0] + lam, h[0, 1], h[0, 2]
    d, e = h[1, 1] + lam, h[1, 2]
    f = h[2, 2] + lam
    # cofactors of the symmetric matrix [[a b c] [b d e] [c e f]]
    ca = d * f - e * e
    cb = c * e - b * f
    cc = b * e - c * d
    det = a * ca + b * cb + c * cc
    if not math.isfinite(det) or abs(det) < 1e-300:
        return False, 0.0, 0.0, 0.0
    cd = a * f - c * c
    ce = b * c - a * e
    cf = a * d - b * b
    inv = -1.0 / det
    return (True, (ca * g0 + cb * g1 + cc * g2) * inv, (cb * g0 + cd * g1 + ce * g2) * inv,
            (cc * g0 + ce * g1 + cf * g2) * inv)


@jit.kernel
def _residuals(a, n, c, s, x, y, inv_k2, r, w):
    """Point-to-line residuals ``r`` and Cauchy weights ``w`` of the first ``n`` association
    rows ``a`` (u, v, nx, ny, n.q) at the pose (c, s, x, y)."""
    for k in range(n):
        r[k] = fma(a[k, 4], -1.0, (a[k, 0] * c + a[k, 2] * x) + (a[k, 1] * s + a[k, 3] * y))
        w[k] = 1.0 / (1.0 + (r[k] * r[k]) * inv_k2)


@jit.kernel
def _normal_equations(a, n, w, c, s, x, y):
    """``(H, g)`` of the Gauss-Newton step: with ``G = (a w)^T a`` (5 x 5) and ``T`` the map
    from (u, v, nx, ny, n.q) to (J_x, J_y, J_theta, r), ``T^T G T = [[H, g], [g^T, .]]``
    (the last row is not needed)."""
    gram = np.empty((5, 5))
    for i in range(5):                    # every sum runs over k in order
        g0 = g1 = g2 = g3 = g4 = 0.0
        for k in range(n):
            aw = a[k, i] * w[k]
            g0 = fma(aw, a[k, 0], g0)
            g1 = fma(aw, a[k, 1], g1)
            g2 = fma(aw, a[k, 2], g2)
            g3 = fma(aw, a[k, 3], g3)
            g4 = fma(aw, a[k, 4], g4)
        gram[i, 0], gram[i, 1], gram[i, 2], gram[i, 3], gram[i, 4] = g0, g1, g2, g3, g4
    t = np.array([[0.0, 0.0, -s, c],
                  [0.0, 0.0, c, s],
                  [c, -s, 0.0, x],
                  [s, c, 0.0, y],
                  [0.0, 0.0, 0.0, -1.0]])
    m = _matmul(_matmul(t.T, gram, 3), t, 3)    # rows 0-2 of T^T G T
    return m[:, :3].copy(), m[0, 3], m[1, 3], m[2, 3]


@jit.kernel
def _matmul(a, b, rows):
    """The first ``rows`` rows of ``a @ b`` as numpy's BLAS computes small products: each
    entry a sequence of fused multiply-adds from zero."""
    out = np.empty((rows, b.shape[1]))
    for p in range(rows):
        for q in range(b.shape[1]):
            acc = 0.0
            for k in range(a.shape[1]):
                acc = fma(a[p, k], b[k, q], acc)
            out[p, q] = acc
    return out


@jit.kernel
def _align(source, pose0, schedule, levels, settings, rows, grid_xy, order, start, grid):
    """The Gauss-Newton iterations of :func:`align` over the first ``levels`` association
    distances of ``schedule``; returns (pose, H, scalars, eigenvalues, eigenvectors, last
    step) with scalars = sum_w, iterations, converged, n_in, rms, scale.

    Sums run in numpy's order (``jit``): the results are those of the numpy formulation
    (residuals ``A [c, s, x, y, -1]``, ``H`` and ``g`` from ``T^T (A w)^T A T``) bit for
    bit."""
    kernel_ratio, steps, damping = settings[_KERNEL_RATIO], int(settings[_STEPS]), \
        settings[_DAMPING]
    stride, n_coarse = int(settings[_STRIDE]), int(settings[_N_COARSE])
    x, y, th = pose0[0], pose0[1], pose0[2]
    m = source.shape[0]
    h = np.zeros((3, 3))
    a = np.empty((m, 5))              # per association: u = n.p, v = n x p, nx, ny, n.q
    matched = np.empty((m, 2))        # the associated scan points
    r = np.empty(m)
    w = np.empty(m)
    tree = _no_tree()
    tied = np.empty(m, np.int64)      # association rows whose nearest map point is tied
    n_in = 0
    iterations = 0
    last0 = last1 = last2 = 0.0
    inv_k2 = 0.0
    if rows.shape[0] == 0 or m == 0:
        levels = 0
    for level in range(levels):
        d = schedule[level]
        c, s = math.cos(th), math.sin(th)
        step = stride if level < n_coarse else 1
        n_in = n_tied = 0
        for i in range(0, m, step):
            px, py = source[i, 0], source[i, 1]
            qx, qy = fma(py, -s, px * c) + x, fma(py, c, px * s) + y
            j, tie = _nearest(qx, qy, d, grid_xy, start, grid)
            if j < 0:
                continue
            if tie:                       # the KD-tree breaks the tie (below)
                tied[n_tied] = n_in
                n_tied += 1
            _associate(a, matched, n_in, rows, order[j], px, py)
            n_in += 1
        if n_tied:    # apart from the loop: the tree there costs every query time
            tree = _untie(a, matched, tied, n_tied, c, s, x, y, d, rows, tree)
        if n_in < 3:
            break
        inv_k2 = 1.0 / (kernel_ratio * d) ** 2
        for _ in range(steps):
            c, s = math.cos(th), math.sin(th)
            _residuals(a, n_in, c, s, x, y, inv_k2, r, w)
            h, g0, g1, g2 = _normal_equations(a, n_in, w, c, s, x, y)
            ok, dx, dy, dt = _solve3(h, g0, g1, g2, damping)
            if not ok:
                break
            x += c * dx - s * dy
            y += s * dx + c * dy
            th = (th + dt + math.pi) % (2.0 * math.pi) - math.pi
            iterations += 1
            last0, last1, last2 = dx, dy, dt
            if abs(dx) + abs(dy) < settings[_TOL_T] and abs(dt) < settings[_TOL_R]:
                break
    converged = (n_in >= 3 and math.hypot(last0, last1) < settings[_CONV_T]
                 and abs(last2) < settings[_CONV_R])
    sum_w, rms, scale = 0.0, math.inf, 1.0
    evals, evecs = np.zeros(3), np.eye(3)
    if n_in >= 3:
        _residuals(a, n_in, math.cos(th), math.sin(th), x, y, inv_k2, r, w)
        sum_w = pairwise_sum(w, 0, n_in)
        for k in range(n_in):
            r[k] = r[k] * r[k]
        rms = math.sqrt(blas_dot(w, r, n_in) / max(sum_w, 1e-12))
        flat = matched[:n_in].ravel()
        scale = max(math.sqrt(einsum_dot(flat, flat, 2 * n_in) / n_in), 0.1)
        sv = np.array([1.0, 1.0, 1.0 / scale])
        norm = np.empty((3, 3))
        for i in range(3):
            for j in range(3):
                norm[i, j] = h[i, j] * (sv[i] * sv[j]) / max(sum_w, 1e-12)
        evals, evecs = np.linalg.eigh(norm)
    scalars = np.array([sum_w, iterations, converged, n_in, rms, scale])
    return (np.array([x, y, th]), h, scalars, evals, evecs, np.array([last0, last1, last2]))


@jit.kernel
def _scan_points(ranges, skip, cos, sin, valid_min, valid_max, min_range, max_range,
                 max_points):
    """End points of the finite beams with ``valid_min <= r < valid_max`` and
    ``min_range <= r <= max_range`` that ``skip`` does not leave out (empty: none is),
    every ceil(n / max_points)-th of them."""
    n = ranges.shape[0]
    keep = np.empty(n, np.int64)
    m = 0
    for i in range(n):
        r = ranges[i]
        if math.isfinite(r) and valid_min <= r < valid_max and min_range <= r <= max_range \
                and not (skip.size and skip[i]):
            keep[m] = i
            m += 1
    stride = -(-m // max_points) if m > max_points else 1
    out = np.empty(((m + stride - 1) // stride, 2))
    for k in range(out.shape[0]):
        i = keep[k * stride]
        out[k, 0] = ranges[i] * cos[i]
        out[k, 1] = ranges[i] * sin[i]
    return out


#: Layout of a packed match result (one float array: a kernel returns one array, not six;
#: returning each costs about a microsecond): pose, H, the scalars (sum of weights,
#: iterations, converged, inliers, rms, scale), eigenvalues, eigenvectors, last step.
POSE, HESSIAN, SCALARS, EIGENVALUES, EIGENVECTORS, LAST_STEP, RESULT_SIZE = \
    0, 3, 12, 18, 21, 30, 33
_SUM_W, _ITERATIONS, _CONVERGED, _N_IN, _RMS, _SCALE = range(SCALARS, SCALARS + 6)


@jit.kernel
def _points_and_align(ranges, skip, cos, sin, valid_min, valid_max, min_range, max_range,
                      max_points, min_points, pose0, levels, schedule, settings, rows,
                      grid_xy, order, start, grid, out):
    """The scan's points (:func:`_scan_points`) and, with ``levels`` > 0 and at least
    ``min_points`` of them and in the map, their :func:`_align` result packed into
    ``out[:RESULT_SIZE]``; returns the points and whether they were matched."""
    pts = _scan_points(ranges, skip, cos, sin, valid_min, valid_max, min_range, max_range,
                       max_points)
    if pts.shape[0] < min_points or rows.shape[0] < min_points:
        levels = 0
    pose, h, scalars, evals, evecs, last = _align(pts, pose0, schedule, levels, settings,
                                                  rows, grid_xy, order, start, grid)
    out[POSE:POSE + 3] = pose
    out[HESSIAN:HESSIAN + 9] = h.ravel()
    out[SCALARS:SCALARS + 6] = scalars
    out[EIGENVALUES:EIGENVALUES + 3] = evals
    out[EIGENVECTORS:EIGENVECTORS + 9] = evecs.ravel()
    out[LAST_STEP:LAST_STEP + 3] = last
    return pts, levels > 0


# --------------------------------------------------------------------------- Python API


def scan_normals(points: np.ndarray, max_gap: float = 0.3,
                 gap_ratio: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (M, 2) of consecutive scan points (M, 2, beam order) and a mask (M,).

    Neighbours ``i - 1`` and ``i + 1`` belong to point ``i``'s surface when they are closer
    than ``max_gap + gap_ratio * range``; the tangent is the chord between the neighbours
    that belong (or to the one that does). Normals face the scanner. ``mask`` is False for
    isolated points (no neighbour), whose normal is (0, 0).
    """
    return _normals(np.ascontiguousarray(points, dtype=float), float(max_gap),
                    float(gap_ratio))


class LocalMap:
    """Points and normals of the last ``max_scans`` key scans in the world frame, with the
    grid hash of :func:`align`'s neighbour search (rebuilt when a scan joins), in buffers
    that kernels update in place (:attr:`buffers`; :meth:`reserve` makes room first)."""

    def __init__(self, max_scans: int, max_gap: float = 0.3, gap_ratio: float = 0.05,
                 capacity: int = 1024):
        self.max_scans = int(max_scans)
        self.max_gap, self.gap_ratio = float(max_gap), float(gap_ratio)
        self.state = np.zeros(_SIZES + self.max_scans, np.int64)
        self.state[_MOST] = self.max_scans
        self.buffers = ()
        self._allocate(max(int(capacity), 16))

    def _allocate(self, capacity: int) -> None:
        """Buffers for ``capacity`` rows, holding what the map has."""
        n = self.n_points
        old = self.arrays if n else None
        rows, grid_xy = np.zeros((capacity, 5)), np.zeros((capacity, 2))
        order = np.zeros(capacity, np.int64)
        start = np.zeros(_hash_size(capacity) + 1, np.int64)
        grid = np.zeros(7)
        if old is not None:
            rows[:n], grid_xy[:n], order[:n] = old[0], old[1], old[2]
            start[:old[3].size], grid[:] = old[3], old[4]
        #: what the kernels read and write: the rows (oldest scan first), the points (x, y)
        #: in grid order and their indices in the rows, bucket starts, the grid, :attr:`state`
        self.buffers = (rows, grid_xy, order, start, grid, self.state)

    def reserve(self, extra: int) -> None:
        """Room for ``extra`` more rows."""
        need = self.n_points + int(extra)
        if need > self.buffers[0].shape[0]:
            self._allocate(max(need, 2 * self.buffers[0].shape[0]))

    @property
    def arrays(self) -> tuple:
        """The map as :func:`align` reads it: the rows, the points (x, y) in grid order and
        their indices in the rows, bucket starts, the grid (views of the buffers)."""
        rows, grid_xy, order, start, grid, _ = self.buffers
        n = self.n_points
        return rows[:n], grid_xy[:n], order[:n], start[:int(grid[_MASK]) + 2], grid

    @property
    def rows(self) -> np.ndarray:
        """(N, 5): x, y, nx, ny, n . (x, y) per map point, oldest scan first."""
        return self.buffers[0][:self.n_points]

    @property
    def n_scans(self) -> int:
        return int(self.state[_SCANS])

    @property
    def n_points(self) -> int:
        return int(self.state[_ROWS])

    def clear(self) -> None:
        self.state[_ROWS] = self.state[_SCANS] = 0
        _grid_hash(self.buffers[0], 0, CELL, *self.buffers[1:5])

    def add_scan(self, pose, points: np.ndarray) -> None:
        """One scan's points (scanner frame, beam order) seen from ``pose`` (world): those
        with a normal join; the oldest scan leaves when there are ``max_scans``."""
        points = np.ascontiguousarray(points, dtype=float)
        self.reserve(points.shape[0])
        _add_scan(points, np.asarray(pose, dtype=float), self.max_gap, self.gap_ratio, CELL,
                  *self.buffers)


@dataclass
class IcpResult:
    """Outcome of :func:`align` (the caller applies its acceptance rules)."""

    pose: np.ndarray            # (3,) final scanner pose in the world frame
    hessian: np.ndarray         # (3, 3) J^T W J at the solution (scanner-frame perturbation)
    sum_weights: float          # sum of the robust weights of the final associations
    iterations: int             # Gauss-Newton steps taken
    converged: bool             # the last step was below the convergence limits
    n_source: int
    n_inliers: int              # source points associated within the final distance
    rms: float                  # weighted RMS point-to-line residual (m)
    eigenvalues: np.ndarray     # normalised Hessian eigenvalues (ascending), see align()
    eigenvectors: np.ndarray    # matching eigenvectors (columns), scaled coordinates
    scale: float                # rotation scale L (m) of the normalisation
    last_step: np.ndarray       # the last Gauss-Newton update

    @property
    def inlier_ratio(self) -> float:
        return self.n_inliers / self.n_source if self.n_source else 0.0


@dataclass(frozen=True)
class Schedule:
    """How :func:`align` iterates (see there); ``settings`` is the kernels' form."""

    distances: np.ndarray       # association distance of each level, coarse to fine
    settings: np.ndarray

    @classmethod
    def of(cls, distances=(1.0, 0.5, 0.25, 0.1), kernel_ratio: float = 0.3,
           steps_per_association: int = 2, final_associations: int = 2,
           tol_translation: float = 1e-4, tol_rotation: float = 1e-4, damping: float = 1e-6,
           converged_translation: float = 0.005, converged_rotation: float = 0.002,
           coarse_stride: int = 1) -> Schedule:
        final = max(1, int(final_associations))
        levels = np.array(list(distances[:-1]) + [distances[-1]] * final, dtype=float)
        settings = np.zeros(9)
        settings[_KERNEL_RATIO], settings[_STEPS] = kernel_ratio, max(1, int(steps_per_association))
        settings[_TOL_T], settings[_TOL_R], settings[_DAMPING] = \
            tol_translation, tol_rotation, damping
        settings[_CONV_T], settings[_CONV_R] = converged_translation, converged_rotation
        settings[_STRIDE], settings[_N_COARSE] = coarse_stride, len(levels) - final
        return cls(levels, settings)


def align(source: np.ndarray, ref: LocalMap, pose0, distances=(1.0, 0.5, 0.25, 0.1),
          kernel_ratio: float = 0.3, steps_per_association: int = 2,
          final_associations: int = 2, tol_translation: float = 1e-4,
          tol_rotation: float = 1e-4, damping: float = 1e-6,
          converged_translation: float = 0.005,
          converged_rotation: float = 0.002, coarse_stride: int = 1) -> IcpResult:
    """Align ``source`` points (M, 2, scanner frame) to ``ref`` starting at ``pose0``.

    Coarse-to-fine: for each association distance ``d`` in ``distances`` the source points
    are associated once with their nearest map point within ``d``; then up to
    ``steps_per_association`` Gauss-Newton steps on the point-to-line residuals
    ``n . (T p - q)`` with Cauchy weights of scale ``kernel_ratio * d`` are taken with those
    associations (fewer when a step is below the tolerances). The last distance is
    associated ``final_associations`` times; the coarser levels use every
    ``coarse_stride``-th point. ``damping`` (relative to the Hessian's trace) keeps a
    degenerate problem solvable; the caller decides what a degenerate result means. The
    result is ``converged`` when the last step is below ``converged_translation`` (m) and
    ``converged_rotation`` (rad): the estimate no longer moves.

    The normalised Hessian ``S H S / sum(w)`` with ``S = diag(1, 1, 1/L)`` (``L`` the RMS
    range of the matched points) has eigenvalues equal to the weighted fraction of points
    that constrain each direction (1 for a translation constrained by every point).
    """
    schedule = Schedule.of(distances, kernel_ratio, steps_per_association, final_associations,
                           tol_translation, tol_rotation, damping, converged_translation,
                           converged_rotation, coarse_stride)
    source = np.ascontiguousarray(source, dtype=float)
    return _result(_align(source, np.asarray(pose0, dtype=float), schedule.distances,
                          schedule.distances.shape[0], schedule.settings, *ref.arrays),
                   source.shape[0])


def nearest(ref: LocalMap, queries: np.ndarray, distance: float) -> np.ndarray:
    """For each query point (world frame), the index of the nearest map point (a row of
    ``ref.rows``) strictly within ``distance``, else -1: exactly what
    ``cKDTree(ref.rows[:, :2]).query(queries, distance_upper_bound=distance)`` answers,
    ties included. (:func:`align` associates so.)"""
    return _nearest_all(np.ascontiguousarray(queries, dtype=float), float(distance),
                        *ref.arrays)


def match_scan(ranges: np.ndarray, cos: np.ndarray, sin: np.ndarray, valid_min: float,
               valid_max: float, min_range: float, max_range: float, max_points: int,
               min_points: int, ref: LocalMap, pose0, schedule: Schedule,
               skip: np.ndarray | None = None) -> tuple[np.ndarray, IcpResult | None]:
    """A scan's points and their match, in one kernel call: the end points (scanner frame)
    of the finite beams with ``valid_min <= r < valid_max`` (the scanner's valid readings)
    and ``min_range <= r <= max_range``, except those ``skip`` (bool per beam) leaves out,
    evenly thinned to at most ``max_points``; and, from ``pose0`` (None: no match wanted),
    their :func:`align` result when there are at least ``min_points`` of them and in
    ``ref`` (else None)."""
    levels = 0 if pose0 is None else schedule.distances.shape[0]
    out = np.empty(RESULT_SIZE)
    pts, matched = _points_and_align(
        ranges, NO_SKIP if skip is None else skip, cos, sin, valid_min, valid_max, min_range,
        max_range, max_points, min_points,
        _ORIGIN if pose0 is None else np.asarray(pose0, dtype=float), levels,
        schedule.distances, schedule.settings, *ref.arrays, out)
    return pts, (result(out, pts.shape[0]) if matched else None)


#: ``skip`` of :func:`match_scan` leaving no beam out.
NO_SKIP = np.zeros(0, np.bool_)
_ORIGIN = np.zeros(3)


def warm_up() -> None:
    """Compile (or load from the cache) the kernels now, once per process, for the argument
    types of real scans (the beam table's read-only arrays included), so that no scan
    compiles."""
    from laser_tracker.core.scan import beam_table

    def call():
        _, cos, sin = beam_table(-1.5, 0.075, 41)
        ranges = 2.0 + 0.1 * np.cos(3.0 * np.arange(41) * 0.075)
        local = LocalMap(2)
        schedule = Schedule.of()
        pts, _ = match_scan(ranges, cos, sin, 0.0, 10.0, 0.0, 10.0, 100, 3, local, None,
                            schedule)
        local.add_scan(np.zeros(3), pts)
        local.clear()
        local.add_scan(np.zeros(3), pts)
        match_scan(ranges, cos, sin, 0.0, 10.0, 0.0, 10.0, 100, 3, local, np.zeros(3),
                   schedule)
        nearest(local, pts, 0.1)
        scan_normals(pts)
    jit.compiled('ego-motion kernels (ICP)', call)


def _result(raw, n_source: int) -> IcpResult:
    pose, h, scalars, evals, evecs, last = raw
    sum_w, iterations, converged, n_in, rms, scale = scalars.tolist()
    return IcpResult(pose=pose, hessian=h, sum_weights=sum_w, iterations=int(iterations),
                     converged=bool(converged), n_source=n_source, n_inliers=int(n_in),
                     rms=rms, eigenvalues=evals, eigenvectors=evecs, scale=scale,
                     last_step=last)


def result(packed: np.ndarray, n_source: int) -> IcpResult:
    """The :class:`IcpResult` of a packed result (``POSE`` ... ``LAST_STEP``; its arrays
    are views of ``packed``)."""
    sum_w, iterations, converged, n_in, rms, scale = packed[SCALARS:SCALARS + 6].tolist()
    return IcpResult(packed[POSE:POSE + 3], packed[HESSIAN:HESSIAN + 9].reshape(3, 3), sum_w,
                     int(iterations), converged != 0.0, n_source, int(n_in), rms,
                     packed[EIGENVALUES:EIGENVALUES + 3],
                     packed[EIGENVECTORS:EIGENVECTORS + 9].reshape(3, 3), scale,
                     packed[LAST_STEP:LAST_STEP + 3])
