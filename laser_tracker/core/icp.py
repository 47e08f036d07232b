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
    hessian: np.ndarray         # (3, 3) point term J^T W J at the solution (scanner frame)
    information: np.ndarray     # (3, 3) H / sigma^2 + prior information
    iterations: int
    converged: bool
    n_source: int
    n_inliers: int              # matched within the final association distance
    rms: float                  # weighted RMS point-to-line residual of the inliers (m)
    eigenvalues: np.ndarray     # normalised Hessian eigenvalues (ascending), see align()
    eigenvectors: np.ndarray    # matching eigenvectors (columns), scaled coordinates
    scale: float                # rotation scale L (m) used for the normalisation
    sigma: float                # estimated point residual sigma (m)

    @property
    def inlier_ratio(self) -> float:
        return self.n_inliers / self.n_source if self.n_source else 0.0


def align(source: np.ndarray, ref: LocalMap, pose0, prior_pose=None,
          prior_information=None, distances=(1.0, 0.5, 0.25, 0.1), kernel_ratio: float = 0.3,
          max_iterations: int = 20, tol_translation: float = 1e-4,
          tol_rotation: float = 1e-4, min_iterations_per_level: int = 1) -> IcpResult:
    """Align ``source`` points (M, 2, scanner frame) to ``ref`` starting at ``pose0``.

    Gauss-Newton on the point-to-line residuals ``n . (T p - q)`` with Cauchy weights of
    scale ``kernel_ratio * d`` where ``d`` is the current association distance; ``distances``
    is the coarse-to-fine schedule (the next level starts when an update is below the
    tolerances; convergence = that at the last level). ``prior_pose`` with
    ``prior_information`` (3x3, scanner-frame perturbation, 1/m^2 and 1/rad^2) adds a Gaussian
    prior; residual information is normalised by the residual variance estimated each
    iteration.

    The normalised Hessian is ``S H S / sum(w)`` with ``S = diag(1, 1, 1/L)`` and ``L`` the
    RMS range of the matched points: its eigenvalues are the weighted fraction of points that
    constrain each direction (1 for a translation constrained by every point).
    """
    ref.build()
    pose = np.array(pose0, dtype=float)
    n_src = source.shape[0]
    px = source[:, 0]
    py = source[:, 1]
    ref_pts = ref.points
    ref_nrm = ref.normals
    n_ref = ref_pts.shape[0]
    tree = ref.tree
    zero3 = np.zeros((3, 3))
    if prior_pose is None or prior_information is None:
        prior_pose, lam = None, zero3
    else:
        lam = np.asarray(prior_information, dtype=float)
    level = 0
    level_iters = 0
    converged = False
    it = 0
    hess = zero3
    info = zero3
    n_in = 0
    rms = float('inf')
    sigma2 = 0.05 ** 2
    sum_w = 0.0
    scale = 1.0
    src_xy = np.empty((n_src, 2))
    for it in range(1, max_iterations + 1):
        d = distances[level]
        c, s = math.cos(pose[2]), math.sin(pose[2])
        src_xy[:, 0] = c * px - s * py + pose[0]
        src_xy[:, 1] = s * px + c * py + pose[1]
        dist, idx = tree.query(src_xy, k=1, distance_upper_bound=d)
        sel = np.nonzero(idx < n_ref)[0]
        n_in = sel.size
        if n_in < 3:
            break
        j = idx[sel]
        nrm = ref_nrm[j]
        diff = src_xy[sel] - ref_pts[j]
        r = nrm[:, 0] * diff[:, 0] + nrm[:, 1] * diff[:, 1]
        # scanner-frame normal and rotation Jacobian
        nsx = c * nrm[:, 0] + s * nrm[:, 1]
        nsy = -s * nrm[:, 0] + c * nrm[:, 1]
        pxs, pys = px[sel], py[sel]
        jac = np.empty((n_in, 3))
        jac[:, 0] = nsx
        jac[:, 1] = nsy
        jac[:, 2] = pxs * nsy - pys * nsx
        k = kernel_ratio * d
        w = 1.0 / (1.0 + (r * (1.0 / k)) ** 2)
        jw = jac * w[:, None]
        hess = jw.T @ jac
        grad = jw.T @ r
        sum_w = float(w.sum())
        wr2 = float(w @ (r * r))
        sigma2 = max(wr2 / max(sum_w - 3.0, 1.0), 1e-6)
        info = hess / sigma2
        b = grad / sigma2
        if prior_pose is not None:
            e = _between(prior_pose, pose)
            info = info + lam
            b = b + lam @ e
        try:
            delta = -np.linalg.solve(info, b)
        except np.linalg.LinAlgError:
            break
        pose = _compose(pose, delta)
        level_iters += 1
        small = abs(delta[0]) + abs(delta[1]) < tol_translation and abs(delta[2]) < tol_rotation
        if small and level_iters >= min_iterations_per_level:
            if level == len(distances) - 1:
                converged = True
                break
            level += 1
            level_iters = 0
        elif level < len(distances) - 1 and level_iters >= 4:
            level += 1
            level_iters = 0
    rms = math.sqrt(sigma2)
    if n_in >= 3:
        scale = max(math.sqrt(float(np.mean(px[sel] ** 2 + py[sel] ** 2))), 0.1)
        sv = np.array([1.0, 1.0, 1.0 / scale])
        hn = hess * np.outer(sv, sv) / max(sum_w, 1e-9)
        evals, evecs = np.linalg.eigh(hn)
    else:
        evals, evecs = np.zeros(3), np.eye(3)
    return IcpResult(pose=pose, hessian=hess, information=info, iterations=it,
                     converged=converged, n_source=n_src, n_inliers=int(n_in), rms=rms,
                     eigenvalues=evals, eigenvectors=evecs, scale=scale,
                     sigma=math.sqrt(sigma2))


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
