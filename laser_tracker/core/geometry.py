"""Planar rigid motions (SE(2)) as ``(x, y, theta)`` triples, vectorised where it matters."""
from __future__ import annotations

import numpy as np


def wrap_angle(theta):
    """Angle(s) wrapped to [-pi, pi)."""
    return (np.asarray(theta) + np.pi) % (2.0 * np.pi) - np.pi


def rotation(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


def compose(a, b) -> np.ndarray:
    """``a (+) b``: pose ``b`` expressed in frame ``a``, brought to a's parent frame."""
    ax, ay, at = a
    bx, by, bt = b
    c, s = np.cos(at), np.sin(at)
    return np.array([ax + c * bx - s * by, ay + s * bx + c * by, float(wrap_angle(at + bt))])


def inverse(a) -> np.ndarray:
    ax, ay, at = a
    c, s = np.cos(at), np.sin(at)
    return np.array([-c * ax - s * ay, s * ax - c * ay, float(wrap_angle(-at))])


def between(a, b) -> np.ndarray:
    """Relative motion from pose ``a`` to pose ``b``: ``inverse(a) (+) b``."""
    return compose(inverse(a), b)


def transform_points(pose, points: np.ndarray) -> np.ndarray:
    """Points (N, 2) in the frame of ``pose`` expressed in its parent frame."""
    x, y, t = pose
    c, s = np.cos(t), np.sin(t)
    points = np.asarray(points, dtype=float)
    out = np.empty_like(points)
    out[:, 0] = c * points[:, 0] - s * points[:, 1] + x
    out[:, 1] = s * points[:, 0] + c * points[:, 1] + y
    return out


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
