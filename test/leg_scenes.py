"""Synthetic scans for the person-detector tests: circles (legs, poles) and wall segments
ray-cast from a scanner at the origin."""
import numpy as np

from laser_tracker.core.scan import Scan


def scene(circles=(), walls=(), n_beams=361, fov=np.pi, range_max=10.0, noise=0.0, seed=0,
          angle_min=None) -> Scan:
    """``circles``: (x, y, radius); ``walls``: (x0, y0, x1, y1) segments; no return = inf."""
    first = -fov / 2 if angle_min is None else angle_min
    angles = first + fov / (n_beams - 1) * np.arange(n_beams)
    c, s = np.cos(angles), np.sin(angles)
    r = np.full(n_beams, np.inf)
    for px, py, radius in circles:
        b = px * c + py * s
        disc = b * b - (px * px + py * py - radius * radius)
        hit = (disc > 0) & (b > 0)
        r = np.where(hit, np.minimum(r, b - np.sqrt(np.maximum(disc, 0.0))), r)
    for x0, y0, x1, y1 in walls:
        dx, dy = x1 - x0, y1 - y0
        den = c * dy - s * dx
        with np.errstate(divide='ignore', invalid='ignore'):
            t = (x0 * dy - y0 * dx) / den
            u = (x0 * s - y0 * c) / den
        hit = (t > 0) & (u >= 0) & (u <= 1)
        r = np.where(hit, np.minimum(r, t), r)
    if noise:
        r = r + np.random.default_rng(seed).normal(0.0, noise, n_beams)
    return Scan(stamp=0.0, ranges=r, angle_min=float(angles[0]),
                angle_increment=float(angles[1] - angles[0]), range_min=0.02,
                range_max=range_max)


def box(x, y, side):
    """The four walls of a square centred at (x, y)."""
    h = side / 2
    corners = [(x - h, y - h), (x + h, y - h), (x + h, y + h), (x - h, y + h)]
    return [(*corners[i], *corners[(i + 1) % 4]) for i in range(4)]
