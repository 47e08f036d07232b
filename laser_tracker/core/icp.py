"""Point-to-line ICP for 2D scans against a short local map; pure numpy/scipy.

The pieces used by :mod:`laser_tracker.core.egomotion`:

* :func:`scan_normals`: a unit normal per scan point from its neighbours along the scan
  (a line fit over a window of beams, broken at range jumps), with a planarity measure.
* :class:`LocalMap`: the last few scans' points and normals in the odometry (world) frame,
  concatenated, with one ``scipy.spatial.cKDTree`` built per change.
* :func:`align`: robust (Cauchy) point-to-line Gauss-Newton on SE(2) with coarse-to-fine
  association distances, a Gaussian prior on the pose (the odometry prediction) and the
  Hessian's eigen-analysis for degeneracy. Returns an :class:`IcpResult`; the caller decides.

Poses are ``(x, y, theta)`` of the scanner in the world frame; a correction ``delta`` is
applied on the right (``pose (+) delta``), so it is expressed in the scanner frame.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree


def scan_normals(points: np.ndarray, window: int = 2, max_gap: float = 0.5,
                 gap_ratio: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Normals (M, 2) and planarity (M,) of consecutive scan points (M, 2), beam order.

    Each point's line is fitted (principal axis) over the points up to ``window`` beams away
    whose distance to their inner neighbour stays below ``max_gap + gap_ratio * range``
    (a range jump ends the segment). The normal points towards the scanner. Planarity is
    ``1 - lambda_min / lambda_max`` of the fit (1 = perfect line); isolated points get 0
    and normal (0, 0).
    """
    m = points.shape[0]
    if m == 0:
        return np.zeros((0, 2)), np.zeros(0)
    x = points[:, 0]
    y = points[:, 1]
    rng = np.hypot(x, y)
    step = np.hypot(np.diff(x), np.diff(y))
    limit = max_gap + gap_ratio * np.minimum(rng[1:], rng[:-1])
    link = step < limit  # link[i]: points i and i+1 belong together
    cnt = np.ones(m)
    sx, sy = x.copy(), y.copy()
    sxx, syy, sxy = x * x, y * y, x * y
    for direction in (1, -1):
        ok = np.ones(m, dtype=bool)
        for k in range(1, window + 1):
            if direction == 1:
                # neighbour i + k reachable from i through links i..i+k-1
                reach = np.zeros(m, dtype=bool)
                if k < m:
                    reach[:m - k] = link[k - 1:] if k == 1 else link[k - 1:]
                ok = ok & reach
                sel = np.nonzero(ok)[0]
                nb = sel + k
            else:
                reach = np.zeros(m, dtype=bool)
                if k < m:
                    reach[k:] = link[:m - k]
                ok = ok & reach
                sel = np.nonzero(ok)[0]
                nb = sel - k
            if sel.size == 0:
                break
            xn, yn = x[nb], y[nb]
            cnt[sel] += 1
            sx[sel] += xn
            sy[sel] += yn
            sxx[sel] += xn * xn
            syy[sel] += yn * yn
            sxy[sel] += xn * yn
    mx, my = sx / cnt, sy / cnt
    cxx = sxx / cnt - mx * mx
    cyy = syy / cnt - my * my
    cxy = sxy / cnt - mx * my
    # principal direction angle; normal is perpendicular
    phi = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy)
    nx, ny = -np.sin(phi), np.cos(phi)
    flip = (nx * x + ny * y) > 0.0  # make the normal face the scanner
    nx[flip] *= -1.0
    ny[flip] *= -1.0
    tr = cxx + cyy
    det = cxx * cyy - cxy * cxy
    disc = np.sqrt(np.maximum(tr * tr / 4.0 - det, 0.0))
    lmax = tr / 2.0 + disc
    lmin = np.maximum(tr / 2.0 - disc, 0.0)
    with np.errstate(invalid='ignore', divide='ignore'):
        planarity = np.where(lmax > 1e-12, 1.0 - lmin / lmax, 0.0)
    planarity[cnt < 3] = 0.0
    normals = np.column_stack((nx, ny))
    normals[cnt < 3] = 0.0
    return normals, planarity


class LocalMap:
    """Points and normals of the last ``max_scans`` scans in the world frame, with a KD-tree."""

    def __init__(self, max_scans: int):
        self.max_scans = int(max_scans)
        self._scans: deque = deque(maxlen=self.max_scans)
        self._dirty = True
        self.points = np.zeros((0, 2))
        self.normals = np.zeros((0, 2))
        self.tree: cKDTree | None = None

    def __len__(self) -> int:
        return int(self.points.shape[0]) if not self._dirty else sum(
            s[0].shape[0] for s in self._scans)

    @property
    def n_scans(self) -> int:
        return len(self._scans)

    def clear(self) -> None:
        self._scans.clear()
        self._dirty = True

    def add(self, pose, points: np.ndarray, normals: np.ndarray) -> None:
        """Add one scan's points and normals (scanner frame) seen from ``pose`` (world)."""
        if points.shape[0] == 0:
            return
        c, s = math.cos(pose[2]), math.sin(pose[2])
        rot = np.array([[c, s], [-s, c]])  # row vectors: p @ rot = R p
        self._scans.append((points @ rot + np.asarray(pose[:2]), normals @ rot))
        self._dirty = True

    def build(self) -> None:
        """Concatenate the scans and build the KD-tree (no-op when nothing changed)."""
        if not self._dirty:
            return
        if self._scans:
            self.points = np.concatenate([s[0] for s in self._scans])
            self.normals = np.concatenate([s[1] for s in self._scans])
            self.tree = cKDTree(self.points, leafsize=16, balanced_tree=False,
                                compact_nodes=False)
        else:
            self.points = np.zeros((0, 2))
            self.normals = np.zeros((0, 2))
            self.tree = None
        self._dirty = False


@dataclass
class IcpResult:
    """Outcome of :func:`align` (the caller applies its acceptance rules)."""

    pose: np.ndarray            # (3,) final scanner pose in the world frame
    hessian: np.ndarray         # (3, 3) J^T W J at the solution (scanner-frame perturbation)
    sum_weights: float          # sum of the robust weights of the final associations
    iterations: int
    converged: bool
    n_source: int
    n_inliers: int              # matched within the final association distance
    rms: float                  # weighted RMS point-to-line residual of the inliers (m)
    eigenvalues: np.ndarray     # normalised Hessian eigenvalues (ascending), see align()
    eigenvectors: np.ndarray    # matching eigenvectors (columns), scaled coordinates
    scale: float                # rotation scale L (m) used for the normalisation
    last_step: np.ndarray       # the last Gauss-Newton update (convergence diagnostics)

    @property
    def inlier_ratio(self) -> float:
        return self.n_inliers / self.n_source if self.n_source else 0.0


def align(source: np.ndarray, ref: LocalMap, pose0, distances=(1.0, 0.5, 0.25, 0.1),
          kernel_ratio: float = 0.3, steps_per_association: int = 2,
          final_associations: int = 2, tol_translation: float = 1e-4,
          tol_rotation: float = 1e-4, damping: float = 1e-6) -> IcpResult:
    """Align ``source`` points (M, 2, scanner frame) to ``ref`` starting at ``pose0``.

    Coarse-to-fine: for each association distance ``d`` in ``distances`` the source points
    are associated once with their nearest map point within ``d`` (one KD-tree query for all
    points), then up to ``steps_per_association`` Gauss-Newton steps on the point-to-line
    residuals ``n . (T p - q)`` with Cauchy weights of scale ``kernel_ratio * d`` are taken
    with those associations (stopping early when a step is below the tolerances). The last
    distance is associated ``final_associations`` times. ``damping`` (relative to the
    Hessian's trace) keeps a degenerate problem solvable; the caller handles degeneracy.

    The normalised Hessian ``S H S / sum(w)`` with ``S = diag(1, 1, 1/L)`` (``L`` the RMS
    range of the matched points) has eigenvalues equal to the weighted fraction of points
    that constrain each direction (1 for a translation constrained by every point).
    """
    ref.build()
    pose = np.array(pose0, dtype=float)
    n_src = source.shape[0]
    px_all = source[:, 0]
    py_all = source[:, 1]
    ref_pts = ref.points
    ref_nrm = ref.normals
    n_ref = ref_pts.shape[0]
    tree = ref.tree
    hess = np.zeros((3, 3))
    sum_w = 0.0
    sigma2 = 0.0
    n_in = 0
    iterations = 0
    converged = False
    last_delta = np.zeros(3)
    px = py = np.zeros(0)
    schedule = list(distances[:-1]) + [distances[-1]] * max(1, int(final_associations))
    eye_damp = np.eye(3)
    src_xy = np.empty((n_src, 2))
    for level, d in enumerate(schedule):
        c, s = math.cos(pose[2]), math.sin(pose[2])
        src_xy[:, 0] = c * px_all - s * py_all + pose[0]
        src_xy[:, 1] = s * px_all + c * py_all + pose[1]
        _, idx = tree.query(src_xy, k=1, distance_upper_bound=d)
        sel = idx < n_ref
        n_in = int(np.count_nonzero(sel))
        if n_in < 3:
            break
        j = idx[sel]
        qx = ref_pts[j, 0]
        qy = ref_pts[j, 1]
        nx = ref_nrm[j, 0]
        ny = ref_nrm[j, 1]
        px = px_all[sel]
        py = py_all[sel]
        inv_k2 = 1.0 / (kernel_ratio * d) ** 2
        jac = np.empty((n_in, 3))
        for _ in range(max(1, int(steps_per_association))):
            c, s = math.cos(pose[2]), math.sin(pose[2])
            # scanner-frame normal (R^T n) and the rotation Jacobian n_s x p
            nsx = c * nx + s * ny
            nsy = c * ny - s * nx
            r = nsx * px + nsy * py + (nx * (pose[0] - qx) + ny * (pose[1] - qy))
            jac[:, 0] = nsx
            jac[:, 1] = nsy
            jac[:, 2] = px * nsy - py * nsx
            w = 1.0 / (1.0 + r * r * inv_k2)
            jw = jac * w[:, None]
            hess = jw.T @ jac
            grad = jw.T @ r
            a = hess + (damping * (hess[0, 0] + hess[1, 1] + hess[2, 2]) + 1e-12) * eye_damp
            try:
                delta = -np.linalg.solve(a, grad)
            except np.linalg.LinAlgError:
                break
            pose = _compose(pose, delta)
            iterations += 1
            last_delta = delta
            if abs(delta[0]) + abs(delta[1]) < tol_translation and abs(delta[2]) < tol_rotation:
                break
        last_level = level == len(schedule) - 1
        if last_level:
            converged = (abs(last_delta[0]) + abs(last_delta[1]) < 10 * tol_translation
                         and abs(last_delta[2]) < 10 * tol_rotation)
    if n_in >= 3:
        # residuals at the final pose (for sigma) with the last associations
        c, s = math.cos(pose[2]), math.sin(pose[2])
        r = (c * nx + s * ny) * px + (c * ny - s * nx) * py + (nx * (pose[0] - qx)
                                                             + ny * (pose[1] - qy))
        w = 1.0 / (1.0 + r * r * inv_k2)
        sum_w = float(w.sum())
        sigma2 = float(w @ (r * r)) / max(sum_w, 1e-9)
        scale = max(math.sqrt(float(np.mean(px * px + py * py))), 0.1)
        sv = np.array([1.0, 1.0, 1.0 / scale])
        hn = hess * np.outer(sv, sv) / max(sum_w, 1e-9)
        evals, evecs = np.linalg.eigh(hn)
    else:
        scale = 1.0
        evals, evecs = np.zeros(3), np.eye(3)
    return IcpResult(pose=pose, hessian=hess, sum_weights=sum_w, iterations=iterations,
                     converged=converged, n_source=n_src, n_inliers=n_in,
                     rms=math.sqrt(sigma2), eigenvalues=evals, eigenvectors=evecs,
                     scale=scale, last_step=last_delta)


def _compose(a, b) -> np.ndarray:
    c, s = math.cos(a[2]), math.sin(a[2])
    t = a[2] + b[2]
    t = (t + math.pi) % (2.0 * math.pi) - math.pi
    return np.array([a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], t])


def _between(a, b) -> np.ndarray:
    """inverse(a) (+) b, scalar maths (faster than the vectorised helpers for one pose)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    dx, dy = b[0] - a[0], b[1] - a[1]
    t = b[2] - a[2]
    t = (t + math.pi) % (2.0 * math.pi) - math.pi
    return np.array([c * dx + s * dy, -s * dx + c * dy, t])
