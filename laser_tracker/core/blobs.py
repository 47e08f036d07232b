"""Blob segmentation of the difference map (paper Sec. 6).

The changed cells are grouped into 4-connected components with ``scipy.ndimage.label`` and
a cross-shaped structure (the paper's two-pass labelling). The difference map is sparse (a few
to a few tens of cells), so it is labelled *compressed*: only the rows and columns that hold a
changed cell are kept, with one empty row/column wherever the original had a gap, which
preserves 4-adjacency exactly and labels a tiny array instead of the whole grid (the tests
compare with labelling the full map).

A laser sees only the surface facing it, so a blob's position is the centroid of its visible
cells, tracked as though it were the whole target. Each blob carries:

* ``xy``: centroid in the odometry frame (metres), from the scanner pose ``origin``;
* ``cells``: number of cells; ``extent``: the larger side of its bounding box (metres);
* ``structure``: direction (radians, odometry frame, modulo pi) of the wall-like structure
  it lies on, NaN when there is none (see :func:`structure_angles`). The tracker halves the
  weight of a hypothesis moving along it (paper Sec. 8, the wall penalty).

Visible surfaces are runs of consecutive scan end points (beam order) closer than
``surface_gap``; a blob belongs to the surface of the end point nearest its centroid.

The blobs are :class:`laser_tracker.core.detections.Blobs`, the motion part of what detection
tells tracking (``core.detections.Detections``).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from laser_tracker.config import param
from laser_tracker.core.detections import Blobs

log = logging.getLogger(__name__)

CROSS = ndimage.generate_binary_structure(2, 1)


@dataclass(frozen=True)
class BlobConfig:
    """Blob filtering and structure test (node ``detection``, ``blobs.*``)."""

    min_cells: int = param(1, 'Smallest blob kept, in cells (paper: every blob).', min=1,
                           max=10000)
    max_cells: int = param(0, 'Largest blob kept, in cells; 0 = no limit (paper). A blob much '
                           'larger than any target is usually a misregistered wall.', min=0,
                           max=1000000)
    max_blobs: int = param(200, 'At most this many blobs per scan (the largest are kept and a '
                           'warning is logged); bounds the work after an ego-motion failure.',
                           min=1, max=100000)
    position: str = param('surface', "Where a blob is: 'changed' = centroid of its changed "
                          "cells; 'surface' = centroid of the visible surface they belong to "
                          '(the scan points of the same range-continuous segment within '
                          "surface_radius), the paper's 'surface tracked as though it were "
                          "the entire target'.", choices=('changed', 'surface'))
    surface_gap: float = param(0.15, "Consecutive scan points further apart than this (m) "
                               "belong to different surfaces.", min=0.01, max=5.0)
    surface_radius: float = param(0.5, 'A surface extends at most this far (m) from the '
                                  'changed cells it is found from (for the position and the '
                                  'structure test).', min=0.05, max=5.0)
    centre_offset: float = param(0.3, "Move a blob away from the scanner by this fraction of "
                                 "its surface's width: the centre of a roughly round object "
                                 'lies about half its width behind the surface the laser sees. '
                                 '0 = the surface itself (paper).', min=0.0, max=2.0)
    segment_jump: float = param(0.13, 'Consecutive scan points further apart than this (m) '
                                'end a segment (the compact segments that keep a stopped '
                                "object's track alive; the person detector's clusters when "
                                'it runs).', min=0.01, max=2.0)
    segment_max_width: float = param(1.0, 'Segments wider than this (m, end to end) are '
                                     'structure, not an object.', min=0.05, max=10.0)
    structure_min_points: int = param(6, 'Fewest surface points that can form a wall.', min=3,
                                      max=1000)
    structure_elongation: float = param(3.0, 'Ratio of the principal standard deviations of '
                                        'those points above which they form a line (a wall) '
                                        'with a direction.', min=1.0, max=100.0)


def label_cells(flat: np.ndarray, cells: int) -> tuple[int, np.ndarray, list]:
    """4-connected components of the cells ``flat`` (sorted unique flat indices into a
    cells x cells grid, as ``np.unique`` returns them).

    Returns (number of components, component index 0.. of each cell, and per component
    its bounding box as ``ndimage.find_objects`` slices of the labelled array, whose extents
    are those of the grid). Rows without changed cells are dropped, gaps of more than one row
    shrunk to one empty row, and columns cropped to the occupied span: 4-adjacency is
    unchanged and the array labelled is tiny.
    """
    if flat.size == 0:
        return 0, np.zeros(0, dtype=np.intp), []
    ix, iy = np.divmod(flat, cells)
    cx = np.empty_like(ix)
    cx[0] = 0
    np.cumsum(np.minimum(np.diff(ix), 2), out=cx[1:])   # ix is sorted (flat is)
    cy = iy - iy.min()
    small = np.zeros((int(cx[-1]) + 1, int(cy.max()) + 1), dtype=np.uint8)
    small[cx, cy] = 1
    labels, count = ndimage.label(small, structure=CROSS)
    return int(count), labels[cx, cy].astype(np.intp) - 1, ndimage.find_objects(labels)


def segment(changed: np.ndarray, cells: int, resolution: float, origin, stamp: float,
            config: BlobConfig, points: np.ndarray | None = None) -> Blobs:
    """Blobs of the changed cells ``changed`` (sorted unique flat indices).

    ``origin`` is the scanner pose in the odometry frame; ``points`` the scan's end points in
    beam order (scanner frame), for the surfaces (position and structure; None: neither).
    """
    origin = np.asarray(origin, dtype=float)
    count, labels, boxes = label_cells(changed, cells)
    if count == 0:
        return Blobs.empty()
    ix, iy = np.divmod(changed, cells)
    n = np.bincount(labels, minlength=count)
    half = cells / 2.0 - 0.5
    local = np.empty((count, 2))
    local[:, 0] = np.bincount(labels, ix, count)
    local[:, 1] = np.bincount(labels, iy, count)
    local /= n[:, None]
    local -= half
    local *= resolution
    extent = resolution * np.array([max(b[0].stop - b[0].start, b[1].stop - b[1].start)
                                    for b in boxes], dtype=float)
    dropped = 0
    if config.min_cells > 1 or config.max_cells or count > config.max_blobs:
        keep = n >= config.min_cells
        if config.max_cells:
            keep &= n <= config.max_cells
        if keep.sum() > config.max_blobs:
            order = np.argsort(-n, kind='stable')
            kept = order[keep[order]][:config.max_blobs]
            dropped = int(keep.sum()) - config.max_blobs
            keep = np.zeros(count, dtype=bool)
            keep[kept] = True
            log.warning('%d blobs in one scan at t=%.3f: kept the %d largest '
                        '(blobs.max_blobs)', count, stamp, config.max_blobs)
        local, n, extent = local[keep], n[keep], extent[keep]
    if points is not None and points.shape[0] and local.shape[0]:
        surface = _Surfaces(points, config.surface_gap, local, resolution)
        if config.position == 'surface' and surface.sid.size > 1:
            # Changed components on one visible surface are one blob.
            sid = np.where(surface.sid >= 0, surface.sid, -1 - np.arange(surface.sid.size))
            groups, inverse = np.unique(sid, return_inverse=True)
            if groups.size < sid.size:
                g = groups.size
                total = np.bincount(inverse, n, g)
                local = np.column_stack((np.bincount(inverse, local[:, 0] * n, g),
                                         np.bincount(inverse, local[:, 1] * n, g))) \
                    / total[:, None]
                big = np.zeros(g)
                np.maximum.at(big, inverse, extent)
                n, extent = total.astype(np.int64), big
                surface = _Surfaces(points, config.surface_gap, local, resolution,
                                    surface.id)
        centroid, structure = surface.measure(local, config, resolution)
        structure += origin[2]
        np.mod(structure, np.pi, out=structure)
        if config.position == 'surface':
            local = centroid
    else:
        structure = np.full(local.shape[0], np.nan)
    x, y, t = origin
    c, s = np.cos(t), np.sin(t)
    xy = local @ np.array([[c, s], [-s, c]])
    xy[:, 0] += x
    xy[:, 1] += y
    return Blobs(xy=xy, cells=n.astype(np.int64), extent=extent, structure=structure,
                 dropped=dropped)


class _Surfaces:
    """The scan's visible surfaces (runs of consecutive end points closer than ``gap``) and
    the one each blob centroid lies on (``sid``: the surface of the end point nearest the
    centroid, -1 if none is within a cell diagonal)."""

    def __init__(self, points: np.ndarray, gap: float, centroids: np.ndarray,
                 resolution: float, ids: np.ndarray | None = None):
        self.points = points
        if ids is None:
            step = np.diff(points, axis=0)
            ids = np.empty(points.shape[0], np.intp)
            ids[0] = 0
            np.cumsum(np.einsum('ij,ij->i', step, step) > gap * gap, out=ids[1:])
        self.id = ids
        d = centroids[:, None, :] - points[None, :, :]
        d2 = np.einsum('bmk,bmk->bm', d, d)
        near = d2.argmin(axis=1)
        ok = d2[np.arange(centroids.shape[0]), near] <= 2.0 * resolution ** 2
        self.d2 = d2
        self.sid = np.where(ok, ids[near], -1)

    def measure(self, centroids: np.ndarray, config: BlobConfig,
                resolution: float) -> tuple[np.ndarray, np.ndarray]:
        """Per blob: the position from its surface and the direction of the wall it lies on.

        The surface of a blob is the points of its surface run within ``surface_radius`` of
        its changed cells. Position: their centroid (the blob's own centroid when it has no
        surface), moved away from the scanner by ``centre_offset`` times the surface's width
        (the centre of a roughly round object lies behind its visible surface).

        Wall: the surface has at least ``structure_min_points`` points, their principal
        standard deviations differ by at least ``structure_elongation`` (a line, not a clump
        such as a leg) and the line runs past the blob on both sides: the blob is nearer the
        middle of those points than one standard deviation along the line. That tells a
        misregistered stretch of wall, which continues past its noise blob, from the leading
        edge of an object moving along its own side (a robot's flank), whose surface lies
        behind the blob only (a uniform stretch behind a point has its mean sqrt(3) standard
        deviations away). NaN where there is no wall; else radians mod pi.
        """
        p = self.points
        w = (self.id[None, :] == self.sid[:, None]) & (self.sid >= 0)[:, None] & \
            (self.d2 <= config.surface_radius ** 2)
        feats = np.empty((p.shape[0], 5))
        feats[:, :2] = p
        np.multiply(p, p, out=feats[:, 2:4])
        np.multiply(p[:, 0], p[:, 1], out=feats[:, 4])
        count = w.sum(axis=1)
        m = (w.astype(np.float64) @ feats) / np.maximum(count, 1)[:, None]
        mx, my = m[:, 0], m[:, 1]
        cxx = m[:, 2] - mx * mx
        cyy = m[:, 3] - my * my
        cxy = m[:, 4] - mx * my
        half_tr = 0.5 * (cxx + cyy)
        root = np.sqrt(np.maximum(0.25 * (cxx - cyy) ** 2 + cxy * cxy, 0.0))
        l1 = half_tr + root
        has = count > 0
        out = np.where(has[:, None], m[:, :2], centroids)
        if config.centre_offset > 0 and has.any():
            width = np.sqrt(12.0 * np.maximum(l1, 0.0))      # a uniform stretch's length
            rng = np.maximum(np.hypot(mx, my), 1e-9)
            shift = np.where(has, config.centre_offset * width / rng, 0.0)
            out = out + out * shift[:, None]
        q = resolution * resolution / 12.0                    # quantisation floor
        l1q, l2q = l1 + q, np.maximum(half_tr - root + q, 1e-12)
        angle = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy)
        offset = (mx - centroids[:, 0]) * np.cos(angle) + (my - centroids[:, 1]) * np.sin(angle)
        wall = (count >= config.structure_min_points) & \
            (l1q >= config.structure_elongation ** 2 * l2q) & (offset * offset < l1q)
        return out, np.where(wall, angle, np.nan)


def surface_centroids(centroids: np.ndarray, points: np.ndarray, config: BlobConfig,
                      resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """Surface centroids and wall directions of blobs at ``centroids`` (scanner frame) given
    the scan's end points in beam order: see ``_Surfaces.measure``."""
    return _Surfaces(points, config.surface_gap, centroids, resolution).measure(
        centroids, config, resolution)


def scan_segments(points: np.ndarray, jump: float, max_width: float,
                  min_points: int = 3) -> np.ndarray:
    """Centroids (s, 2) of the compact segments of a scan's end points ``points`` (beam
    order): runs of points closer than ``jump`` to their neighbour, with at least
    ``min_points`` points and at most ``max_width`` between their ends."""
    if points.shape[0] == 0:
        return np.zeros((0, 2))
    step = np.diff(points, axis=0)
    starts = np.concatenate(([0], np.flatnonzero(np.einsum('ij,ij->i', step, step)
                                                  > jump * jump) + 1))
    ends = np.append(starts[1:], points.shape[0]) - 1
    count = ends - starts + 1
    width = np.hypot(*(points[ends] - points[starts]).T)
    keep = (count >= min_points) & (width <= max_width)
    csum = np.zeros((points.shape[0] + 1, 2))
    np.cumsum(points, axis=0, out=csum[1:])
    return ((csum[ends + 1] - csum[starts]) / count[:, None])[keep]
