"""Point-to-line ICP for 2D scans against a short local map; pure numpy/scipy.

The pieces used by :mod:`laser_tracker.core.egomotion`:

* :func:`scan_normals`: a unit normal per scan point from its two neighbours along the scan
  (central difference, one-sided at a segment end, none for an isolated point); a range jump
  larger than ``max_gap + gap_ratio * range`` ends a segment.
* :class:`LocalMap`: the last few scans' points and normals in the odometry (world) frame,
  concatenated, with one ``scipy.spatial.cKDTree`` built per change.
* :func:`align`: robust (Cauchy) point-to-line Gauss-Newton on SE(2) with coarse-to-fine
  association distances; returns an :class:`IcpResult` with the Hessian and its
  normalised eigen-decomposition (degeneracy). Acceptance and the odometry prior are the
  caller's (``egomotion``).

Poses are ``(x, y, theta)`` of the scanner in the world frame; a correction ``delta`` is
applied on the right (``pose (+) delta``), i.e. it is expressed in the scanner frame, and the
Hessian is for that parametrisation.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree


def scan_normals(points: np.ndarray, max_gap: float = 0.3,
                 gap_ratio: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (M, 2) of consecutive scan points (M, 2, beam order) and a mask (M,).

    Neighbours ``i - 1`` and ``i + 1`` belong to point ``i``'s surface when they are closer
    than ``max_gap + gap_ratio * range``; the tangent is the chord between the neighbours
    that belong (or to the one that does). Normals face the scanner. ``mask`` is False for
    isolated points (no neighbour), whose normal is (0, 0).
    """
    m = points.shape[0]
    if m < 2:
        return np.zeros((m, 2)), np.zeros(m, dtype=bool)
    x = points[:, 0]
    y = points[:, 1]
    dx = np.diff(x)
    dy = np.diff(y)
    rng = np.hypot(x, y)
    link = np.hypot(dx, dy) < max_gap + gap_ratio * np.minimum(rng[1:], rng[:-1])
    tx = np.zeros(m)
    ty = np.zeros(m)
    ldx = np.where(link, dx, 0.0)
    ldy = np.where(link, dy, 0.0)
    tx[:-1] += ldx  # forward difference where linked
    ty[:-1] += ldy
    tx[1:] += ldx   # backward difference where linked
    ty[1:] += ldy
    norm = np.hypot(tx, ty)
    ok = norm > 1e-9
    inv = np.where(ok, 1.0 / np.where(ok, norm, 1.0), 0.0)
    nx = -ty * inv
    ny = tx * inv
    flip = (nx * x + ny * y) > 0.0  # face the scanner
    sign = np.where(flip, -1.0, 1.0)
    return np.column_stack((nx * sign, ny * sign)), ok


class LocalMap:
    """Points and normals of the last ``max_scans`` scans in the world frame, with a KD-tree."""

    def __init__(self, max_scans: int):
        self.max_scans = int(max_scans)
        self._scans: deque = deque(maxlen=self.max_scans)
        self._dirty = True
        self.points = np.zeros((0, 2))
        self.normals = np.zeros((0, 2))
        self.data = np.zeros((0, 3))  # nx, ny, n . q per map point
        self.tree: cKDTree | None = None

    @property
    def n_scans(self) -> int:
        return len(self._scans)

    @property
    def n_points(self) -> int:
        return sum(s[0].shape[0] for s in self._scans)

    def clear(self) -> None:
        self._scans.clear()
        self._dirty = True

    def add(self, pose, points: np.ndarray, normals: np.ndarray) -> None:
        """Add one scan's points and normals (scanner frame) seen from ``pose`` (world)."""
        if points.shape[0] == 0:
            return
        c, s = math.cos(pose[2]), math.sin(pose[2])
        rot = np.array([[c, s], [-s, c]])  # row vectors: p @ rot = R p
        self._scans.append((points @ rot + np.asarray(pose[:2], dtype=float), normals @ rot))
        self._dirty = True

    def build(self) -> None:
        """Concatenate the scans and build the KD-tree (no-op when nothing changed)."""
        if not self._dirty:
            return
        if self._scans:
            self.points = np.concatenate([s[0] for s in self._scans])
            self.normals = np.concatenate([s[1] for s in self._scans])
            self.data = np.column_stack((self.normals, np.einsum('ij,ij->i', self.normals,
                                                                  self.points)))
            self.tree = cKDTree(self.points, leafsize=16, balanced_tree=False,
                                compact_nodes=False)
        else:
            self.points = np.zeros((0, 2))
            self.normals = np.zeros((0, 2))
            self.data = np.zeros((0, 3))
            self.tree = None
        self._dirty = False


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


def align(source: np.ndarray, ref: LocalMap, pose0, distances=(1.0, 0.5, 0.25, 0.1),
          kernel_ratio: float = 0.3, steps_per_association: int = 2,
          final_associations: int = 2, tol_translation: float = 1e-4,
          tol_rotation: float = 1e-4, damping: float = 1e-6,
          converged_translation: float = 0.005,
          converged_rotation: float = 0.002, coarse_stride: int = 1) -> IcpResult:
    """Align ``source`` points (M, 2, scanner frame) to ``ref`` starting at ``pose0``.

    Coarse-to-fine: for each association distance ``d`` in ``distances`` the source points
    are associated once with their nearest map point within ``d`` (one KD-tree query for all
    points); then up to ``steps_per_association`` Gauss-Newton steps on the point-to-line
    residuals ``n . (T p - q)`` with Cauchy weights of scale ``kernel_ratio * d`` are taken
    with those associations (fewer when a step is below the tolerances). The last distance is
    associated ``final_associations`` times. ``damping`` (relative to the Hessian's trace)
    keeps a degenerate problem solvable; the caller decides what a degenerate result means.
    The result is ``converged`` when the last step is below ``converged_translation`` (m)
    and ``converged_rotation`` (rad): the estimate no longer moves.

    The normalised Hessian ``S H S / sum(w)`` with ``S = diag(1, 1, 1/L)`` (``L`` the RMS
    range of the matched points) has eigenvalues equal to the weighted fraction of points
    that constrain each direction (1 for a translation constrained by every point).
    """
    ref.build()
    x, y, th = (float(v) for v in pose0)
    n_src = source.shape[0]
    ref_data = ref.data
    n_ref = ref_data.shape[0]
    tree = ref.tree
    h = np.zeros((3, 3))
    n_in = 0
    iterations = 0
    last = (0.0, 0.0, 0.0)
    if tree is None or n_src == 0:
        schedule = []
    else:
        schedule = list(distances[:-1]) + [distances[-1]] * max(1, int(final_associations))
    steps = max(1, int(steps_per_association))
    w = r = None
    bm = psel = None
    n_coarse = len(schedule) - max(1, int(final_associations))
    for level, d in enumerate(schedule):
        c, s = math.cos(th), math.sin(th)
        src = source[::coarse_stride] if level < n_coarse else source
        src_xy = src @ np.array([[c, s], [-s, c]])
        src_xy += (x, y)
        _, idx = tree.query(src_xy, k=1, distance_upper_bound=d)
        sel = idx < n_ref
        j = idx[sel]
        n_in = j.size
        if n_in < 3:
            break
        # Per association, with world normal n, map point q and scan point p (scanner frame):
        # columns u = n . p, v = n x p, nx, ny, n . q. For a pose (c, s, x, y):
        #   residual r = c u + s v + nx x + ny y - n.q
        #   Jacobian (right perturbation) [c nx + s ny, c ny - s nx, c v - s u]
        # so every step is one (M, 5) product plus a 5x5 weighted Gram matrix.
        psel = src[sel]
        md = ref_data[j]  # nx, ny, n.q
        bm = np.empty((n_in, 5))
        bm[:, 2:5] = md
        np.einsum('ij,ij->i', md[:, :2], psel, out=bm[:, 0])
        np.einsum('ij,ij->i', md[:, :2], psel @ _PERP, out=bm[:, 1])
        inv_k2 = 1.0 / (kernel_ratio * d) ** 2
        for _ in range(steps):
            c, s = math.cos(th), math.sin(th)
            r = bm @ np.array([c, s, x, y, -1.0])
            w = 1.0 / (1.0 + (r * r) * inv_k2)
            gram = (bm * w[:, None]).T @ bm
            # columns of the map from (u, v, nx, ny, nq) to (Jx, Jy, Jt, r)
            cm = np.array([[0.0, 0.0, -s, c],
                           [0.0, 0.0, c, s],
                           [c, -s, 0.0, x],
                           [s, c, 0.0, y],
                           [0.0, 0.0, 0.0, -1.0]])
            m = cm.T @ gram @ cm  # [[H, g], [g^T, sum w r^2]]
            h = m[:3, :3]
            delta = _solve3(h, m[:3, 3], damping)
            if delta is None:
                break
            dx, dy, dt = delta
            x += c * dx - s * dy
            y += s * dx + c * dy
            th = (th + dt + math.pi) % (2.0 * math.pi) - math.pi
            iterations += 1
            last = delta
            if abs(dx) + abs(dy) < tol_translation and abs(dt) < tol_rotation:
                break
    converged = (n_in >= 3 and math.hypot(last[0], last[1]) < converged_translation
                 and abs(last[2]) < converged_rotation)
    if n_in >= 3 and bm is not None:
        c, s = math.cos(th), math.sin(th)
        r = bm @ np.array([c, s, x, y, -1.0])
        w = 1.0 / (1.0 + (r * r) * inv_k2)
        sum_w = float(w.sum())
        rms = math.sqrt(float(w @ (r * r)) / max(sum_w, 1e-12))
        scale = max(math.sqrt(float(np.einsum('ij,ij->', psel, psel)) / n_in), 0.1)
        sv = np.array([1.0, 1.0, 1.0 / scale])
        evals, evecs = np.linalg.eigh(h * np.outer(sv, sv) / max(sum_w, 1e-12))
    else:
        sum_w, rms, scale = 0.0, float('inf'), 1.0
        evals, evecs = np.zeros(3), np.eye(3)
    return IcpResult(pose=np.array([x, y, th]), hessian=np.array(h), sum_weights=sum_w,
                     iterations=iterations, converged=bool(converged), n_source=n_src,
                     n_inliers=n_in, rms=rms, eigenvalues=evals, eigenvectors=evecs,
                     scale=scale, last_step=np.array(last, dtype=float))


_PERP = np.array([[0.0, 1.0], [-1.0, 0.0]])  # (px, py) @ _PERP = (-py, px)


def _solve3(h, g, damping: float):
    """``-(H + damping * trace(H) * I)^-1 g`` for a symmetric 3x3 H (Cramer's rule)."""
    lam = damping * (h[0, 0] + h[1, 1] + h[2, 2]) + 1e-12
    a, b, c = float(h[0, 0]) + lam, float(h[0, 1]), float(h[0, 2])
    d, e = float(h[1, 1]) + lam, float(h[1, 2])
    f = float(h[2, 2]) + lam
    # cofactors of the symmetric matrix [[a b c] [b d e] [c e f]]
    A = d * f - e * e
    B = c * e - b * f
    C = b * e - c * d
    det = a * A + b * B + c * C
    if not math.isfinite(det) or abs(det) < 1e-300:
        return None
    D = a * f - c * c
    E = b * c - a * e
    F = a * d - b * b
    g0, g1, g2 = float(g[0]), float(g[1]), float(g[2])
    inv = -1.0 / det
    return ((A * g0 + B * g1 + C * g2) * inv,
            (B * g0 + D * g1 + E * g2) * inv,
            (C * g0 + E * g1 + F * g2) * inv)
