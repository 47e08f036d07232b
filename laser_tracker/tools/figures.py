"""Figures like the paper's, drawn with matplotlib (Agg backend, no display needed).

* :func:`tracks_figure`: Fig. 10, the confirmed tracks over a recording, each track's
  positions coloured by id with its velocity vectors, the scanner path in grey.
* :func:`scan_figure`: Fig. 5 / Fig. 7 for one scan: (a) current grid, (b) previous grid in
  the current frame, (c) difference map (changes white, no valid data grey), (d) the
  hypotheses' velocities over the scan (lines; confirmed ones marked with a cross).

Every file is written atomically (``laser_tracker.tools.atomic``).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

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


def tracks_figure(rows: np.ndarray, scanner: np.ndarray, path: str | Path,
                  title: str = '', background: np.ndarray | None = None,
                  arrow_period: float = 0.4) -> Path:
    """Fig. 10. ``rows`` (k, 6): stamp, id, x, y, vx, vy of confirmed tracks (odometry frame);
    ``scanner`` (n, 3) scanner poses; ``background`` (m, 2) scan points for context (e.g. the
    first scan, odometry frame). Each track is a line coloured by id with velocity arrows
    (one second of travel) every ``arrow_period`` seconds."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 7))
    if background is not None and background.shape[0]:
        ax.plot(background[:, 0], background[:, 1], '.', color='0.75', ms=1.5,
                label='scan (first)')
    if scanner.shape[0]:
        ax.plot(scanner[:, 0], scanner[:, 1], color='0.5', lw=1, label='scanner')
        ax.plot(scanner[-1, 0], scanner[-1, 1], marker='s', color='0.4', ms=6)
    ids = np.unique(rows[:, 1]).astype(int) if rows.shape[0] else np.zeros(0, int)
    cmap = plt.get_cmap('tab20')
    for i, tid in enumerate(ids):
        r = rows[rows[:, 1] == tid]
        colour = cmap(i % 20)
        ax.plot(r[:, 2], r[:, 3], '-', color=colour, lw=1)
        slot = np.floor((r[:, 0] - r[0, 0]) / max(arrow_period, 1e-6))
        a = r[np.concatenate(([True], slot[1:] != slot[:-1]))]
        ax.quiver(a[:, 2], a[:, 3], a[:, 4], a[:, 5], color=colour, angles='xy',
                  scale_units='xy', scale=1.0, width=0.003)
        ax.annotate(str(tid), r[0, 2:4], fontsize=7, color=colour)
    ax.set_aspect('equal', adjustable='datalim')
    ax.set_xlabel('x (m, odometry frame)')
    ax.set_ylabel('y (m)')
    ax.set_title(title or f'confirmed tracks ({ids.size}) with velocity (1 s of travel)')
    ax.grid(True, lw=0.3)
    if scanner.shape[0] or background is not None:
        ax.legend(loc='upper right', fontsize=8)
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
        diff[det.difference] = 1.0            # changes: white
    fig, axes = plt.subplots(2, 2, figsize=(11, 11))
    panels = [(axes[0, 0], _grid_image(grid), '(a) current grid'),
              (axes[0, 1], _grid_image(previous), '(b) previous grid, current frame'),
              (axes[1, 0], diff, '(c) difference map (Eq. 1)')]
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
    b = result.blobs
    if b.count:
        loc = b.local()
        ax.plot(loc[:, 0], loc[:, 1], 'o', mfc='none', color='tab:green', ms=6)
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
