"""Figures like the paper's, drawn with matplotlib (Agg backend, no display needed).

* :func:`tracks_figure`: Fig. 10, the confirmed tracks over a recording, each track's
  positions coloured by id with its velocity vectors, the scanner path in grey.
* :func:`scan_figure`: Fig. 5 / Fig. 7 for one scan: (a) current grid, (b) previous grid in
  the current frame, (c) difference map (changes white, no valid data grey), (d) the
  hypotheses' velocities over the scan (lines; confirmed ones marked with a cross).

Every file is written atomically (``laser_tracker.io.atomic``).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from laser_tracker.core.grid import FREE, OCCUPIED, UNKNOWN
from laser_tracker.io.atomic import atomic_path


def _plt():
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


def _save(fig, path: Path) -> Path:
    path = Path(path)
    with atomic_path(path, overwrite=True) as tmp:
        fig.savefig(tmp, dpi=110, format=path.suffix.lstrip('.') or 'png')
    return path


def tracks_figure(rows: np.ndarray, scanner: np.ndarray, path: str | Path,
                  title: str = '', max_arrows: int = 4000) -> Path:
    """Fig. 10. ``rows`` (k, 6): stamp, id, x, y, vx, vy of confirmed tracks (odometry frame);
    ``scanner`` (n, 3) scanner poses. Arrows show one second of travel."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 7))
    if scanner.shape[0]:
        ax.plot(scanner[:, 0], scanner[:, 1], color='0.6', lw=1, label='scanner')
        ax.plot(scanner[-1, 0], scanner[-1, 1], marker='s', color='0.4', ms=6)
    ids = np.unique(rows[:, 1]).astype(int) if rows.shape[0] else np.zeros(0, int)
    cmap = plt.get_cmap('tab20')
    step = max(1, int(np.ceil(rows.shape[0] / max_arrows))) if rows.shape[0] else 1
    for i, tid in enumerate(ids):
        r = rows[rows[:, 1] == tid]
        colour = cmap(i % 20)
        ax.plot(r[:, 2], r[:, 3], '.', color=colour, ms=3)
        a = r[::step]
        ax.quiver(a[:, 2], a[:, 3], a[:, 4], a[:, 5], color=colour, angles='xy',
                  scale_units='xy', scale=1.0, width=0.003)
        ax.annotate(str(tid), r[0, 2:4], fontsize=7, color=colour)
    ax.set_aspect('equal', adjustable='datalim')
    ax.set_xlabel('x (m, odometry frame)')
    ax.set_ylabel('y (m)')
    ax.set_title(title or f'confirmed tracks ({ids.size}) with velocity (1 s of travel)')
    ax.grid(True, lw=0.3)
    if scanner.shape[0]:
        ax.legend(loc='upper right', fontsize=8)
    fig.tight_layout()
    out = _save(fig, path)
    plt.close(fig)
    return out


def _grid_image(grid: np.ndarray) -> np.ndarray:
    img = np.full(grid.shape + (3,), 0.6)
    img[grid == FREE] = 1.0
    img[grid == OCCUPIED] = 0.0
    return img


def scan_figure(result, resolution: float, path: str | Path, title: str = '') -> Path:
    """Fig. 5 / Fig. 7 for one ``StepResult`` computed with ``want_grids=True``."""
    plt = _plt()
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
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    for a in axes.ravel():
        a.set_xlabel('x (m, scanner frame)')
        a.set_ylabel('y (m)')
    fig.suptitle(title or f'scan at t = {result.stamp:.3f} s')
    fig.tight_layout()
    out = _save(fig, path)
    plt.close(fig)
    return out
