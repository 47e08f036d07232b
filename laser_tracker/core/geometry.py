"""Planar rigid motions (SE(2)) as ``(x, y, theta)`` triples, vectorised where it matters.

Single poses use ``math`` (a few times faster than numpy on scalars: they are on per-scan
paths); arrays of points or angles use numpy.
"""
from __future__ import annotations

import math

import numpy as np

_TWO_PI = 2.0 * math.pi
_FLOAT64 = np.dtype(np.float64)


def wrap_angle(theta):
    """Angle(s) wrapped to [-pi, pi)."""
    return (np.asarray(theta) + np.pi) % (2.0 * np.pi) - np.pi


def wrap_scalar(theta: float) -> float:
    """One angle wrapped to [-pi, pi)."""
    return (theta + math.pi) % _TWO_PI - math.pi


def rotation(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


def plain_floats(p):
    """A 1-D float64 array's items as Python floats (the same values, and the same results
    of arithmetic on them, faster than on numpy scalars); anything else as it is."""
    return p.tolist() if type(p) is np.ndarray and p.dtype is _FLOAT64 and p.ndim == 1 else p


def compose(a, b) -> np.ndarray:
    """``a (+) b``: pose ``b`` expressed in frame ``a``, brought to a's parent frame."""
    ax, ay, at = plain_floats(a)
    bx, by, bt = plain_floats(b)
    c, s = math.cos(at), math.sin(at)
    return np.array([ax + c * bx - s * by, ay + s * bx + c * by, wrap_scalar(at + bt)])


def inverse(a) -> np.ndarray:
    ax, ay, at = a
    c, s = math.cos(at), math.sin(at)
    return np.array([-c * ax - s * ay, s * ax - c * ay, wrap_scalar(-at)])


def between(a, b) -> np.ndarray:
    """Relative motion from pose ``a`` to pose ``b``: ``inverse(a) (+) b``."""
    ax, ay, at = plain_floats(a)[:3]
    bx, by, bt = plain_floats(b)[:3]
    c, s = math.cos(at), math.sin(at)
    dx, dy = bx - ax, by - ay
    return np.array([c * dx + s * dy, -s * dx + c * dy, wrap_scalar(bt - at)])


def pairwise_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Euclidean distances (len(a), len(b)) between two sets of 2D points."""
    if a.shape[0] == 0 or b.shape[0] == 0:
        return np.zeros((a.shape[0], b.shape[0]))
    d = a[:, None, :] - b[None, :, :]
    return np.sqrt(np.einsum('ijk,ijk->ij', d, d))


def transform_points(pose, points: np.ndarray) -> np.ndarray:
    """Points (N, 2) in the frame of ``pose`` expressed in its parent frame."""
    x, y, t = pose
    c, s = np.cos(t), np.sin(t)
    points = np.asarray(points, dtype=float)
    out = np.empty_like(points)
    out[:, 0] = c * points[:, 0] - s * points[:, 1] + x
    out[:, 1] = s * points[:, 0] + c * points[:, 1] + y
    return out


def points_in_frame(pose, points: np.ndarray) -> np.ndarray:
    """Points (N, 2) of the parent frame expressed in the frame of ``pose`` (the inverse of
    :func:`transform_points`)."""
    x, y, t = pose
    c, s = np.cos(t), np.sin(t)
    d = np.asarray(points, dtype=float) - np.array([x, y])
    return np.column_stack((c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]))


def interpolate_poses(stamps: np.ndarray, poses: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Poses (N, 3) at sorted ``stamps`` linearly interpolated (angles unwrapped) at ``query``.

    Queries outside the stamps are clamped to the end poses; callers that care check the range.
    """
    stamps = np.asarray(stamps, dtype=float)
    poses = np.asarray(poses, dtype=float)
    query = np.atleast_1d(np.asarray(query, dtype=float))
    theta = np.unwrap(poses[:, 2])
    out = np.empty((query.size, 3))
    out[:, 0] = np.interp(query, stamps, poses[:, 0])
    out[:, 1] = np.interp(query, stamps, poses[:, 1])
    out[:, 2] = wrap_angle(np.interp(query, stamps, theta))
    return out
