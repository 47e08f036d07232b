"""A 2D world of line segments and circles, and vectorised ray casting against it.

Everything the scanner can see at its mounting height is a segment (walls, desk panels,
cabinets, boxes, the sides of another robot) or a circle (table, chair and human legs, bins,
pillars). :func:`cast` intersects every beam with every segment and circle at once.
Glass panes are segments apart (``World.glass``): specular, they return a beam only near
normal incidence and let the others through (:func:`cast_scene`).

Segments are rows ``(x0, y0, x1, y1)``, circles rows ``(cx, cy, r)``, in metres, world frame.
Moving geometry (legs, robots) is passed per beam: arrays of shape ``(N, S, 4)`` /
``(N, C, 3)`` hold where each object was when beam ``n`` was taken.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

_EPS = 1e-12


def ray_segment_distances(origins: np.ndarray, directions: np.ndarray,
                          segments: np.ndarray) -> np.ndarray:
    """Distance along each ray to each segment, ``inf`` where the ray misses.

    ``origins``, ``directions``: (N, 2), directions of unit length; ``segments``: (S, 4) shared
    by all rays or (N, S, 4) per ray. Returns (N, S).
    """
    segments = np.asarray(segments, dtype=float)
    n = origins.shape[0]
    if segments.shape[-2] == 0:
        return np.full((n, 0), np.inf)
    ox, oy = origins[:, 0:1], origins[:, 1:2]
    dx, dy = directions[:, 0:1], directions[:, 1:2]
    px, py = segments[..., 0], segments[..., 1]
    ex, ey = segments[..., 2] - px, segments[..., 3] - py
    denom = dx * ey - dy * ex                       # cross(d, e)
    qx, qy = px - ox, py - oy                       # p - o
    with np.errstate(divide='ignore', invalid='ignore'):
        t = (qx * ey - qy * ex) / denom              # along the ray
        s = (qx * dy - qy * dx) / denom              # along the segment
    hit = (np.abs(denom) > _EPS) & (t > 1e-9) & (s >= 0.0) & (s <= 1.0)
    return np.where(hit, t, np.inf)


def ray_circle_distances(origins: np.ndarray, directions: np.ndarray,
                         circles: np.ndarray) -> np.ndarray:
    """Distance along each ray to the near side of each circle, ``inf`` where it misses.

    ``circles``: (C, 3) shared or (N, C, 3) per ray. A ray starting inside a circle does not
    see it (the scanner is never inside an obstacle). Returns (N, C).
    """
    circles = np.asarray(circles, dtype=float)
    n = origins.shape[0]
    if circles.shape[-2] == 0:
        return np.full((n, 0), np.inf)
    cx = circles[..., 0] - origins[:, 0:1]
    cy = circles[..., 1] - origins[:, 1:2]
    r = circles[..., 2]
    b = cx * directions[:, 0:1] + cy * directions[:, 1:2]
    c = cx * cx + cy * cy - r * r
    disc = b * b - c
    with np.errstate(invalid='ignore'):
        t = b - np.sqrt(disc)
    hit = (disc >= 0.0) & (c > 0.0) & (t > 1e-9)
    return np.where(hit, t, np.inf)


def cast(origins: np.ndarray, directions: np.ndarray, segment_sets, circle_sets):
    """Nearest hit along each ray over several groups of segments and circles.

    ``segment_sets`` / ``circle_sets``: lists of ``(geometry, owner)`` where geometry is as
    for the functions above and ``owner`` an int array with one entry per segment / circle
    (the id reported for a hit on it; 0 = static world). Returns ``(ranges (N,), owners (N,))``
    with ``inf`` and -1 where a ray hits nothing.
    """
    best, owner, _ = _nearest(origins, directions, segment_sets, circle_sets, False)
    return best, owner


def cast_scene(origins: np.ndarray, directions: np.ndarray, segment_sets, circle_sets,
               glass: np.ndarray | None = None):
    """As :func:`cast`, with glass panels and each hit's angle of incidence.

    ``glass`` (G, 5) rows ``(x0, y0, x1, y1, lobe)``: a specular panel returns a beam only
    within ``lobe`` rad of its normal (it reflects the rest away, or lets it through), so a
    beam it does not return goes on to whatever lies behind it. Returns ``(ranges (N,),
    owners (N,), incidence (N,))``: incidence is the hit's angle from the surface normal
    (rad, 0 = head-on, pi/2 = grazing), NaN where nothing is hit; a glass return is owned
    by the static world (0).
    """
    best, owner, incidence = _nearest(origins, directions, segment_sets, circle_sets, True)
    glass = np.zeros((0, 5)) if glass is None else np.asarray(glass, dtype=float)
    if len(glass):
        dist = ray_segment_distances(origins, directions, glass[:, :4])
        cos_inc = _segment_cos_incidence(directions, glass[None, :, :4])
        dist = np.where(cos_inc >= np.cos(glass[None, :, 4]), dist, np.inf)
        j = np.argmin(dist, axis=1)
        rows = np.arange(origins.shape[0])
        d = dist[rows, j]
        closer = d < best
        best = np.where(closer, d, best)
        owner = np.where(closer, 0, owner)
        incidence = np.where(closer, np.arccos(np.clip(cos_inc[rows, j], 0.0, 1.0)),
                             incidence)
    return best, owner, incidence


def _segment_cos_incidence(directions: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """|cos| of the angle between each ray (N, 2) and the normal of each segment (N or 1,
    S, 4): ``|cross(d, e)| / |e|``."""
    ex, ey = segments[..., 2] - segments[..., 0], segments[..., 3] - segments[..., 1]
    cross = directions[:, 0:1] * ey - directions[:, 1:2] * ex
    return np.abs(cross) / np.maximum(np.hypot(ex, ey), _EPS)


def _nearest(origins, directions, segment_sets, circle_sets, with_incidence: bool):
    n = origins.shape[0]
    best = np.full(n, np.inf)
    owner = np.full(n, -1, dtype=np.int64)
    incidence = np.full(n, np.nan) if with_incidence else None
    rows = np.arange(n)
    groups = [(ray_segment_distances, g, o) for g, o in segment_sets] + \
             [(ray_circle_distances, g, o) for g, o in circle_sets]
    for func, geometry, owners in groups:
        owners = np.asarray(owners, dtype=np.int64)
        if owners.size == 0:
            continue
        dist = func(origins, directions, geometry)
        j = np.argmin(dist, axis=1)
        d = dist[rows, j]
        closer = d < best
        best = np.where(closer, d, best)
        owner = np.where(closer, owners[j], owner)
        if with_incidence and closer.any():
            geometry = np.asarray(geometry, dtype=float)
            hit = geometry[j] if geometry.ndim == 2 else geometry[rows, j]      # (N, 4 or 3)
            if func is ray_segment_distances:
                cos_inc = _segment_cos_incidence(directions, hit[:, None, :])[:, 0]
            else:
                with np.errstate(invalid='ignore'):
                    px = origins[:, 0] + directions[:, 0] * d - hit[:, 0]
                    py = origins[:, 1] + directions[:, 1] * d - hit[:, 1]
                    cos_inc = np.abs(directions[:, 0] * px + directions[:, 1] * py) / hit[:, 2]
            with np.errstate(invalid='ignore'):
                angle = np.arccos(np.clip(cos_inc, 0.0, 1.0))
            incidence = np.where(closer, angle, incidence)
    return best, owner, incidence


@dataclass
class World:
    """The static scene: walls, doorways (gaps), furniture and clutter.

    Build it with the helpers (``wall``, ``room``, ``box``, ``table``, ``chair``, ...);
    ``segments`` (S, 4) and ``circles`` (C, 3) are the arrays the ray caster uses.
    """

    _segments: list = field(default_factory=list)
    _circles: list = field(default_factory=list)
    _glass: list = field(default_factory=list)

    @property
    def segments(self) -> np.ndarray:
        return np.array(self._segments, dtype=float).reshape(-1, 4)

    @property
    def circles(self) -> np.ndarray:
        return np.array(self._circles, dtype=float).reshape(-1, 3)

    @property
    def glass(self) -> np.ndarray:
        """Glass panels (G, 5): ``(x0, y0, x1, y1, lobe)``, lobe in rad (see :func:`cast_scene`)."""
        return np.array(self._glass, dtype=float).reshape(-1, 5)

    @property
    def solid(self) -> np.ndarray:
        """Every segment a body cannot pass (walls and glass), (S, 4): for clearances."""
        return np.concatenate([self.segments, self.glass[:, :4]])

    # ------------------------------------------------------------------ primitives
    def wall(self, x0: float, y0: float, x1: float, y1: float) -> World:
        self._segments.append((x0, y0, x1, y1))
        return self

    def polyline(self, points, closed: bool = False) -> World:
        pts = [tuple(p) for p in points]
        if closed:
            pts.append(pts[0])
        for (x0, y0), (x1, y1) in zip(pts[:-1], pts[1:]):
            self.wall(x0, y0, x1, y1)
        return self

    def circle(self, x: float, y: float, r: float) -> World:
        self._circles.append((x, y, r))
        return self

    def glass_panel(self, x0: float, y0: float, x1: float, y1: float,
                    lobe_deg: float = 3.0) -> World:
        """A glass pane: it returns a beam only within ``lobe_deg`` of its normal."""
        self._glass.append((x0, y0, x1, y1, math.radians(lobe_deg)))
        return self

    def thick_wall(self, x0: float, y0: float, x1: float, y1: float,
                   thickness: float = 0.15) -> World:
        """A wall with both faces and its end faces (the jambs of the doors beside it): a
        rectangle from (x0, y0) to (x1, y1) along its centre line."""
        length = math.hypot(x1 - x0, y1 - y0)
        return self.box((x0 + x1) / 2.0, (y0 + y1) / 2.0, length, thickness,
                        math.atan2(y1 - y0, x1 - x0))

    # ------------------------------------------------------------------ furniture
    def box(self, cx: float, cy: float, length: float, width: float, yaw: float = 0.0) -> World:
        """A solid rectangle (cabinet, desk with side panels, crate): its 4 sides."""
        self.polyline(box_corners(cx, cy, length, width, yaw), closed=True)
        return self

    def table(self, cx: float, cy: float, length: float, width: float, yaw: float = 0.0,
              leg_radius: float = 0.025) -> World:
        """A table: at scanner height only its four legs (inset 5 cm from the corners)."""
        for x, y in box_corners(cx, cy, length - 0.1, width - 0.1, yaw):
            self.circle(x, y, leg_radius)
        return self

    def chair(self, cx: float, cy: float, yaw: float = 0.0, size: float = 0.42,
              leg_radius: float = 0.015) -> World:
        """A four-legged chair: four thin legs, much like a person's legs to a laser."""
        return self.table(cx, cy, size, size, yaw, leg_radius)

    def room(self, x0: float, y0: float, x1: float, y1: float, doors=()) -> World:
        """A rectangular room; ``doors`` = ``[(side, centre, width)]`` with side one of
        'south' (y = y0), 'north' (y = y1), 'west' (x = x0), 'east' (x = x1) and centre the
        coordinate along that wall. A door is a gap in the wall."""
        sides = {'south': ((x0, y0), (x1, y0)), 'north': ((x0, y1), (x1, y1)),
                 'west': ((x0, y0), (x0, y1)), 'east': ((x1, y0), (x1, y1))}
        for side, ((ax, ay), (bx, by)) in sides.items():
            horizontal = ay == by
            lo, hi = (ax, bx) if horizontal else (ay, by)
            gaps = sorted((c - w / 2.0, c + w / 2.0) for s, c, w in doors if s == side)
            start = lo
            for g0, g1 in gaps + [(hi, hi)]:
                if g0 > start:
                    if horizontal:
                        self.wall(start, ay, g0, ay)
                    else:
                        self.wall(ax, start, ax, g0)
                start = max(start, g1)
        return self


def clearance(points: np.ndarray, segments: np.ndarray, circles: np.ndarray) -> np.ndarray:
    """Distance (P,) from each point (P, 2) to the nearest segment or circle boundary
    (negative inside a circle): how much room a walker or the platform has."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    best = np.full(points.shape[0], np.inf)
    if len(segments):
        a, b = segments[None, :, 0:2], segments[None, :, 2:4]
        ab = b - a
        ap = points[:, None, :] - a
        u = np.clip(np.sum(ap * ab, axis=-1) / np.maximum(np.sum(ab * ab, axis=-1), _EPS),
                    0.0, 1.0)
        d = np.linalg.norm(ap - u[..., None] * ab, axis=-1)
        best = np.minimum(best, d.min(axis=1))
    if len(circles):
        d = np.linalg.norm(points[:, None, :] - circles[None, :, :2], axis=-1) - circles[None, :, 2]
        best = np.minimum(best, d.min(axis=1))
    return best


def box_corners(cx: float, cy: float, length: float, width: float, yaw: float = 0.0):
    """Corners (4, 2) of a rectangle centred at (cx, cy), ``length`` along ``yaw``."""
    c, s = math.cos(yaw), math.sin(yaw)
    hl, hw = length / 2.0, width / 2.0
    local = ((hl, hw), (-hl, hw), (-hl, -hw), (hl, -hw))
    return np.array([(cx + c * x - s * y, cy + s * x + c * y) for x, y in local])
