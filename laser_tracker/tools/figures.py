"""Figures like the paper's, drawn with matplotlib (Agg backend, no display needed).

* :func:`tracks_figure`: Fig. 10, the confirmed tracks over a recording: the longest ones
  coloured and labelled with their id and a few velocity arrows, the others thin and grey,
  the scanner path black and dashed (start triangle, end square). :func:`draw_tracks` and
  :func:`draw_scanner` draw the same on any axes (``laser-tracker evaluate`` figures).
* :func:`scan_figure`: Fig. 5 / Fig. 7 for one scan: (a) current grid, (b) previous grid in
  the current frame, (c) difference map (changes white, no valid data grey), (d) the
  hypotheses' velocities over the scan (lines; confirmed ones marked with a cross).

Every file is written atomically (``laser_tracker.tools.atomic``).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from laser_tracker.core.geometry import points_in_frame
from laser_tracker.core.grid import FREE, OCCUPIED, UNKNOWN
from laser_tracker.tools.atomic import atomic_path


def pyplot():
    """matplotlib.pyplot on the Agg backend (no display needed)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


def save_figure(fig, path: str | Path) -> Path:
    """Save atomically (no half-written image after an error)."""
    path = Path(path)
    with atomic_path(path, overwrite=True) as tmp:
        fig.savefig(tmp, dpi=110, format=path.suffix.lstrip('.') or 'png')
    return path


#: Distinct roles: tracks take the palette, never these colours.
GROUND_TRUTH_COLOUR = 'tab:green'
SCANNER_COLOUR = 'black'
FALSE_COLOUR = 'tab:red'
MINOR_COLOUR = '0.55'
_PALETTE = ('tab:blue', 'tab:orange', 'tab:purple', 'tab:brown', 'tab:pink', 'tab:olive',
            'tab:cyan', 'navy', 'darkgoldenrod', 'teal')


def broken_path(poses: np.ndarray, jump: float = 2.0, segments=None) -> np.ndarray:
    """x, y of a pose sequence with NaN where it jumps by more than ``jump`` metres, returns
    exactly to the origin (an ego-motion restart without odometry) or, when given, where
    ``segments`` (one run number per pose) changes."""
    arr = np.asarray(poses, float)
    arr = arr.reshape(arr.shape[0], -1) if arr.size else np.zeros((0, 2))
    keep = np.all(np.isfinite(arr[:, :2]), axis=1)
    xy, origin = arr[keep, :2], np.all(arr[keep] == 0.0, axis=1)
    cut = (np.hypot(*np.diff(xy, axis=0).T) > jump) | origin[1:]
    if segments is not None:
        seg = np.asarray(segments)[keep]
        cut |= seg[1:] != seg[:-1]
    return np.insert(xy, np.flatnonzero(cut) + 1, np.nan, axis=0)


def draw_scanner(ax, poses: np.ndarray, label: str = 'scanner path', segments=None) -> None:
    """The scanner path, black dashed, with its start (triangle) and end (square); broken at
    ego-motion restarts (``segments``, see :func:`broken_path`)."""
    xy = broken_path(poses, segments=segments)
    if not xy.size:
        return
    ax.plot(xy[:, 0], xy[:, 1], color=SCANNER_COLOUR, lw=0.9, ls='--', alpha=0.8, label=label,
            zorder=2)
    ok = xy[np.all(np.isfinite(xy), axis=1)]
    ax.plot(*ok[0], marker='^', color=SCANNER_COLOUR, ms=7, ls='none', zorder=5)
    ax.plot(*ok[-1], marker='s', color=SCANNER_COLOUR, ms=6, ls='none', zorder=5)


def _outlined(colour: str):
    from matplotlib import patheffects
    return {'color': colour, 'fontsize': 8, 'fontweight': 'bold', 'zorder': 7,
            'path_effects': [patheffects.withStroke(linewidth=2.5, foreground='white')]}


MAX_ARROW = 2.0   # m: longer velocity arrows (ghosts with absurd speeds) are cut to this


def draw_tracks(ax, stamp, track_id, x, y, vx=None, vy=None, false_ids=(), max_labels: int = 25,
                arrow_s: float = 1.0, arrow_every: float = 5.0) -> int:
    """Tracks on ``ax``: the ``max_labels`` longest-lived (false ones first) in distinct
    colours with their id at their last position and a velocity arrow (``arrow_s`` seconds of
    travel, at most ``MAX_ARROW`` long) every ``arrow_every`` seconds, at most three; the
    others thin and grey; false tracks red with crosses. Returns how many are labelled."""
    stamp, track_id = np.asarray(stamp, float), np.asarray(track_id)
    x, y = np.asarray(x, float), np.asarray(y, float)
    false_ids = {int(i) for i in false_ids}
    ids = np.unique(track_id)
    rows = {int(t): np.flatnonzero(track_id == t) for t in ids}
    for t, r in rows.items():
        rows[t] = r[np.argsort(stamp[r], kind='stable')]
    ranked = sorted(rows, key=lambda t: (t not in false_ids, -rows[t].size, t))
    labelled = set(ranked[:max_labels])
    colour_of = {t: _PALETTE[i % len(_PALETTE)]
                 for i, t in enumerate(t for t in ranked if t in labelled and t not in false_ids)}
    for t in sorted(rows, key=lambda t: t in labelled):   # minor ones underneath
        r = rows[t]
        bad = t in false_ids
        if t not in labelled:
            ax.plot(x[r], y[r], 'x-' if bad else '-', color=FALSE_COLOUR if bad else MINOR_COLOUR,
                    lw=0.6, ms=3, alpha=0.6, zorder=3)
            continue
        colour = FALSE_COLOUR if bad else colour_of[t]
        ax.plot(x[r], y[r], 'x-' if bad else '.-', color=colour, lw=1.4, ms=4 if bad else 3,
                zorder=4)
        ax.annotate(str(t), (x[r[-1]], y[r[-1]]), xytext=(3, 3), textcoords='offset points',
                    **_outlined(colour))
        if vx is None or arrow_s <= 0 or r.size < 2:
            continue
        slot = np.floor((stamp[r] - stamp[r[0]]) / arrow_every)
        first = r[np.concatenate(([True], slot[1:] != slot[:-1]))]
        pick = first[:3] if first.size > 1 else r[[r.size // 2]]
        u, v = arrow_s * np.asarray(vx)[pick], arrow_s * np.asarray(vy)[pick]
        cut = np.minimum(1.0, MAX_ARROW / np.maximum(np.hypot(u, v), 1e-9))
        ax.quiver(x[pick], y[pick], u * cut, v * cut, angles='xy', scale_units='xy', scale=1.0,
                  color=colour, width=0.0035, headwidth=3.5, headlength=4,
                  headaxislength=3.5, zorder=6)
    return len(labelled)


def fit_view(ax, *xy_arrays, pad: float = 1.0) -> None:
    """Equal-aspect limits that show every finite point of ``xy_arrays`` ((n, >=2) each)."""
    pts = [np.asarray(a, float).reshape(-1, np.shape(a)[-1])[:, :2] for a in xy_arrays
           if a is not None and np.size(a)]
    pts = np.vstack(pts) if pts else np.zeros((0, 2))
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if pts.shape[0] == 0:
        return
    lo, hi = pts.min(axis=0) - pad, pts.max(axis=0) + pad
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect('equal', adjustable='box')


def tracks_legend(ax, n_tracks: int, n_labelled: int, arrow_s: float = 1.0,
                  false: int | None = None) -> None:
    """Legend entries for :func:`draw_tracks` (proxy artists) and the legend itself."""
    arrows = (f'; arrow = {arrow_s:g} s of travel (at most {MAX_ARROW:g} m)' if arrow_s > 0
              else '')
    ax.plot([], [], '.-', color=_PALETTE[0], label=f'track, id at its end{arrows}')
    if n_labelled < n_tracks:
        ax.plot([], [], '-', color=MINOR_COLOUR,
                label=f'other tracks ({n_tracks - n_labelled}, ids not shown)')
    if false:
        ax.plot([], [], 'x-', color=FALSE_COLOUR, label=f'false track ({false})')
    ax.legend(loc='best', fontsize=8, framealpha=0.85)


def tracks_figure(rows: np.ndarray, scanner: np.ndarray, path: str | Path,
                  title: str = '', background: np.ndarray | None = None,
                  max_labels: int = 25) -> Path:
    """Fig. 10. ``rows`` (k, 6): stamp, id, x, y, vx, vy of confirmed tracks (odometry frame);
    ``scanner`` (n, 3) scanner poses; ``background`` (m, 2) scan points for context (e.g. the
    first scan, odometry frame). The ``max_labels`` longest tracks are drawn in colour with
    their id and velocity arrows (1 s of travel), the others thin and grey."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(9, 8))
    if background is not None and background.shape[0]:
        ax.plot(background[:, 0], background[:, 1], '.', color='0.75', ms=1.5,
                label='scan (first)', zorder=1)
    draw_scanner(ax, scanner)
    rows = np.asarray(rows, float).reshape(-1, 6)
    n = int(np.unique(rows[:, 1]).size)
    shown = draw_tracks(ax, rows[:, 0], rows[:, 1].astype(int), rows[:, 2], rows[:, 3],
                        rows[:, 4], rows[:, 5], max_labels=max_labels) if n else 0
    fit_view(ax, rows[:, 2:4], scanner, background, pad=MAX_ARROW)
    ax.set_xlabel('x (m, odometry frame)')
    ax.set_ylabel('y (m)')
    ax.set_title(title or f'confirmed tracks ({n})')
    ax.grid(True, lw=0.3)
    tracks_legend(ax, n, shown)
    fig.tight_layout()
    out = save_figure(fig, path)
    plt.close(fig)
    return out


def _grid_image(grid: np.ndarray) -> np.ndarray:
    img = np.full(grid.shape + (3,), 0.6)
    img[grid == FREE] = 1.0
    img[grid == OCCUPIED] = 0.0
    return img


def scan_figure(result, resolution: float, path: str | Path, title: str = '') -> Path:
    """Fig. 5 / Fig. 7 for one ``StepResult`` computed with ``want_grids=True``."""
    plt = pyplot()
    det = result.detection
    grid = det.grid
    if grid is None:
        raise ValueError('scan_figure needs a step computed with want_grids=True')
    n = grid.shape[0]
    half = n * resolution / 2.0
    extent = (-half, half, -half, half)
    previous = det.previous if det.previous is not None else np.full_like(grid, UNKNOWN)
    diff = np.full(grid.shape + (3,), 0.0)
    diff[previous == UNKNOWN] = 0.6           # no valid data before: grey (Fig. 5c)
    if det.difference is not None:
        diff[det.difference] = 1.0            # Eq. 1 against the previous grid: white
    made = np.zeros(grid.shape, bool)
    if det.changed_cells is not None and det.changed_cells.size:
        made.ravel()[det.changed_cells] = True
        diff[made] = (1.0, 0.15, 0.0)          # the cells that made the blobs: red
    fig, axes = plt.subplots(2, 2, figsize=(11, 11))
    panels = [(axes[0, 0], _grid_image(grid), '(a) current grid'),
              (axes[0, 1], _grid_image(previous), '(b) previous grid, current frame'),
              (axes[1, 0], diff, f'(c) difference map: Eq. 1 (white), the {int(made.sum())} '
                                 f'cells that made the blobs (red)')]
    for ax, img, name in panels:
        # grid[ix, iy]: x forward is the image's horizontal axis.
        ax.imshow(np.transpose(img, (1, 0, 2)), origin='lower', extent=extent,
                  interpolation='nearest')
        ax.set_title(name)
    ax = axes[1, 1]
    ax.imshow(np.transpose(_grid_image(grid), (1, 0, 2)), origin='lower', extent=extent,
              interpolation='nearest', alpha=0.5)
    h = result.hypotheses
    if len(h):
        x, y, t = result.pose
        c, s = np.cos(t), np.sin(t)
        d = h.position - np.array([x, y])
        px, py = c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]
        vx = c * h.velocity[:, 0] + s * h.velocity[:, 1]
        vy = -s * h.velocity[:, 0] + c * h.velocity[:, 1]
        for j in range(len(h)):
            colour = 'tab:red' if h.confirmed[j] else 'tab:blue'
            ax.plot([px[j], px[j] + vx[j]], [py[j], py[j] + vy[j]], color=colour, lw=1.5)
            if h.confirmed[j]:
                ax.plot(px[j], py[j], 'x', color=colour, ms=8, mew=2)
                ax.annotate(str(int(h.track_id[j])), (px[j], py[j]), fontsize=8,
                            color=colour)
    b = result.detections.blobs
    if b.count:
        loc = points_in_frame(result.pose, b.xy)
        ax.plot(loc[:, 0], loc[:, 1], 'o', mfc='none', color='tab:green', ms=6)
        axes[1, 0].plot(loc[:, 0], loc[:, 1], 'o', mfc='none', color='tab:green', ms=9,
                        mew=1.5)
    ax.set_title('(d) hypotheses: velocity (1 s), x = confirmed, o = blob')
    # Show the observed part of the grid (a 180 deg scanner sees half of it).
    seen = np.argwhere((grid != UNKNOWN) | (previous != UNKNOWN))
    if seen.size:
        lo = (seen.min(axis=0) - n / 2.0) * resolution - 0.5
        hi = (seen.max(axis=0) + 1 - n / 2.0) * resolution + 0.5
        lim = (max(lo[0], -half), min(hi[0], half), max(lo[1], -half), min(hi[1], half))
    else:
        lim = extent
    for a in axes.ravel():
        a.set_xlim(lim[0], lim[1])
        a.set_ylim(lim[2], lim[3])
        a.set_xlabel('x (m, scanner frame)')
        a.set_ylabel('y (m)')
    fig.suptitle(title or f'scan at t = {result.stamp:.3f} s')
    fig.tight_layout()
    out = save_figure(fig, path)
    plt.close(fig)
    return out
