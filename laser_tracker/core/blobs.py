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
* ``structure``: direction (radians, odometry frame, modulo pi) of the static structure
  around it, NaN when there is none (see :func:`structure_angles`). The tracker halves the
  weight of a hypothesis moving along it (paper Sec. 8, the wall penalty).

:class:`Blobs` is the whole interface between detection and tracking: plain arrays that
``laser_tracker.core.pipeline`` documents as a MarkerArray schema.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from laser_tracker.config import param
from laser_tracker.core.grid import cell_centres

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
                                  'changed cells it is found from.', min=0.05, max=5.0)
    structure_radius: float = param(0.3, 'Static occupied cells within this distance (m) of a '
                                    "blob's centroid make up the structure it lies on.",
                                    min=0.0, max=5.0)
    structure_min_cells: int = param(4, 'Fewest static cells that count as structure.',
                                     min=1, max=1000)
    structure_elongation: float = param(2.5, 'Ratio of the principal standard deviations of '
                                        'the static cells above which they form a line '
                                        '(a wall) with a direction.', min=1.0, max=100.0)


@dataclass
class Blobs:
    """The blobs of one scan: the detection -> tracking interface (plain arrays)."""

    stamp: float
    origin: np.ndarray                    # (3,) scanner pose x, y, theta in the odometry frame
    xy: np.ndarray                        # (b, 2) centroids, odometry frame, metres
    cells: np.ndarray                     # (b,) int
    extent: np.ndarray                    # (b,) metres
    structure: np.ndarray                 # (b,) radians (odometry frame, mod pi) or NaN
    frame_id: str = 'odom'
    dropped: int = field(default=0)       # blobs dropped by max_blobs

    @property
    def count(self) -> int:
        return int(self.xy.shape[0])

    def __len__(self) -> int:
        return self.count

    @classmethod
    def empty(cls, stamp: float, origin, frame_id: str = 'odom') -> Blobs:
        return cls(stamp=float(stamp), origin=np.asarray(origin, dtype=float),
                   xy=np.zeros((0, 2)), cells=np.zeros(0, dtype=np.int64),
                   extent=np.zeros(0), structure=np.zeros(0), frame_id=frame_id)

    def local(self) -> np.ndarray:
        """Centroids in the scanner frame (for figures)."""
        x, y, t = self.origin
        c, s = np.cos(t), np.sin(t)
        d = self.xy - np.array([x, y])
        return np.column_stack((c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]))


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
            config: BlobConfig, static_xy: np.ndarray | None = None,
            points: np.ndarray | None = None) -> Blobs:
    """Blobs of the changed cells ``changed`` (sorted unique flat indices).

    ``origin`` is the scanner pose in the odometry frame; ``static_xy`` the static occupied
    points (scanner frame) for the structure test (None: no structure); ``points`` the scan's
    end points in beam order (scanner frame) for ``position='surface'``.
    """
    origin = np.asarray(origin, dtype=float)
    count, labels, boxes = label_cells(changed, cells)
    if count == 0:
        return Blobs.empty(stamp, origin)
    centres = cell_centres(cells, resolution, changed)
    n = np.bincount(labels, minlength=count)
    local = np.column_stack((np.bincount(labels, centres[:, 0], count),
                             np.bincount(labels, centres[:, 1], count))) / n[:, None]
    extent = resolution * np.array([max(b[0].stop - b[0].start, b[1].stop - b[1].start)
                                    for b in boxes], dtype=float)
    keep = n >= config.min_cells
    if config.max_cells:
        keep &= n <= config.max_cells
    dropped = 0
    if keep.sum() > config.max_blobs:
        order = np.argsort(-n, kind='stable')
        kept = order[keep[order]][:config.max_blobs]
        dropped = int(keep.sum()) - config.max_blobs
        keep = np.zeros(count, dtype=bool)
        keep[kept] = True
        log.warning('%d blobs in one scan at t=%.3f: kept the %d largest (blobs.max_blobs)',
                    count, stamp, config.max_blobs)
    if not keep.all():
        local, n, extent = local[keep], n[keep], extent[keep]
    surface = None
    if config.position == 'surface' and points is not None and points.shape[0] and \
            local.shape[0]:
        surface = _Surfaces(points, config.surface_gap, local, resolution)
        # Changed components on one visible surface are one blob.
        sid = surface.sid
        if sid.size > 1:
            sid = np.where(sid >= 0, sid, -1 - np.arange(sid.size))
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
    if static_xy is not None and static_xy.shape[0] and local.shape[0]:
        structure = structure_angles(local, static_xy, resolution, config) + origin[2]
        structure = np.mod(structure, np.pi)
    else:
        structure = np.full(local.shape[0], np.nan)
    if surface is not None:
        local = surface.centroids(local, config.surface_radius)
    x, y, t = origin
    c, s = np.cos(t), np.sin(t)
    xy = np.column_stack((x + c * local[:, 0] - s * local[:, 1],
                          y + s * local[:, 0] + c * local[:, 1]))
    return Blobs(stamp=float(stamp), origin=origin, xy=xy, cells=n.astype(np.int64),
                 extent=extent, structure=structure, dropped=dropped)


class _Surfaces:
    """The scan's visible surfaces (runs of consecutive end points closer than ``gap``) and
    the one each blob centroid lies on (``sid``: the surface of the end point nearest the
    centroid, -1 if none is within a cell diagonal)."""

    def __init__(self, points: np.ndarray, gap: float, centroids: np.ndarray,
                 resolution: float, ids: np.ndarray | None = None):
        self.points = points
        if ids is None:
            step = points[1:] - points[:-1]
            ids = np.empty(points.shape[0], np.intp)
            ids[0] = 0
            np.cumsum((step * step).sum(axis=1) > gap * gap, out=ids[1:])
        self.id = ids
        d2 = ((centroids[:, None, :] - points[None, :, :]) ** 2).sum(axis=2)
        near = d2.argmin(axis=1)
        ok = d2[np.arange(centroids.shape[0]), near] <= 2.0 * resolution ** 2
        self.d2 = d2
        self.sid = np.where(ok, ids[near], -1)

    def centroids(self, centroids: np.ndarray, radius: float) -> np.ndarray:
        """Centroid of the surface each blob lies on, limited to ``radius`` around the blob.

        A blob with no surface keeps its own centroid.
        """
        w = (self.id[None, :] == self.sid[:, None]) & (self.d2 <= radius * radius)
        count = w.sum(axis=1)
        use = (self.sid >= 0) & (count > 0)
        if not use.any():
            return centroids
        out = centroids.copy()
        out[use] = (w[use].astype(np.float64) @ self.points) / count[use, None]
        return out


def surface_centroids(centroids: np.ndarray, points: np.ndarray, gap: float, radius: float,
                      resolution: float) -> np.ndarray:
    """Centroid of the visible surface each blob belongs to (scanner frame).

    ``points`` are the scan's end points in beam order. Surfaces are runs of consecutive
    points closer than ``gap``; a blob's surface is the run holding the point nearest its
    centroid, limited to the points within ``radius`` of the centroid. A blob with no point
    within a cell diagonal keeps its centroid.
    """
    return _Surfaces(points, gap, centroids, resolution).centroids(centroids, radius)


def structure_angles(centroids: np.ndarray, static_xy: np.ndarray, resolution: float,
                     config: BlobConfig) -> np.ndarray:
    """Direction of the wall-like structure each centroid lies on (scanner frame), or NaN.

    The static cells within ``structure_radius`` of a centroid form a wall through it when
    there are at least ``structure_min_cells`` of them, their principal standard deviations
    differ by at least ``structure_elongation`` (a line, not a clump) and the line runs past
    the blob on both sides (at least two cells beyond one cell from the centroid each way).
    The last condition tells a misregistered stretch of wall, which continues past its noise
    blob, from the leading edge of an object moving along its own side (a robot's flank),
    which is static behind the blob only. Angle of the principal axis, radians mod pi.
    Vectorised over blobs and cells.
    """
    dx = static_xy[None, :, 0] - centroids[:, None, 0]
    dy = static_xy[None, :, 1] - centroids[:, None, 1]
    near = dx * dx + dy * dy <= config.structure_radius ** 2
    w = near.astype(np.float64)
    count = w.sum(axis=1)
    out = np.full(centroids.shape[0], np.nan)
    ok = count >= config.structure_min_cells
    if not ok.any():
        return out
    w, count, near, dx, dy = w[ok], count[ok], near[ok], dx[ok], dy[ok]
    mx, my = (w * dx).sum(axis=1) / count, (w * dy).sum(axis=1) / count
    q = resolution * resolution / 12.0   # quantisation variance of a cell centre
    cxx = (w * dx * dx).sum(axis=1) / count - mx * mx + q
    cyy = (w * dy * dy).sum(axis=1) / count - my * my + q
    cxy = (w * dx * dy).sum(axis=1) / count - mx * my
    half_tr = 0.5 * (cxx + cyy)
    root = np.sqrt(np.maximum(0.25 * (cxx - cyy) ** 2 + cxy * cxy, 0.0))
    l1, l2 = half_tr + root, np.maximum(half_tr - root, 1e-12)
    line = l1 >= config.structure_elongation ** 2 * l2
    angle = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy)
    along = dx * np.cos(angle)[:, None] + dy * np.sin(angle)[:, None]
    ahead = (near & (along > resolution)).sum(axis=1)
    behind = (near & (along < -resolution)).sum(axis=1)
    wall = line & (ahead >= 2) & (behind >= 2)
    out[ok] = np.where(wall, angle, np.nan)
    return out
