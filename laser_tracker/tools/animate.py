"""``laser-tracker animate RUN``: an animation of the scans with the tracks and their trails.

RUN is a ``laser-tracker replay`` output folder: ``ego_motion.csv`` places each scan,
``tracks.csv`` gives the confirmed tracks, and the scans themselves are read from the recording
named in ``RUN/summary.json`` (or ``--recording``: the replayed recording moved elsewhere, or
a ``replay --record`` recording, whose scans are on ``/scan``). Each frame shows the latest
scan (grey points), every confirmed track as a dot with its id, kind colour
(``conversions.KIND_COLOURS``: people magenta, other objects blue), a velocity arrow (one
second of travel) and its trail, a scale bar and the time since the recording's start; in
the odometry frame (the scanner moves), or with ``--follow`` in the scanner's frame (x
forward, up).

Output: a GIF (Pillow), or an MP4 when the name ends in ``.mp4`` and ``ffmpeg`` is on the
PATH; written whole or not at all. ``--start`` / ``--end`` (seconds from the first scan)
choose the window, ``--fps`` the frames per second of the animation and ``--speed`` how
much faster than real time it plays (each frame shows the last scan at its time), ``--size``
the image side in pixels, ``--view`` the half-width of the view in metres.
"""
from __future__ import annotations

import argparse
import json
import math
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from laser_tracker.errors import InputFileError, LaserTrackerError

TRAIL_S = 5.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('run', metavar='RUN', help='a `laser-tracker replay` output folder')
    parser.add_argument('--out', metavar='FILE',
                        help='the animation: .gif, or .mp4 with ffmpeg (default RUN/animation.gif)')
    parser.add_argument('--recording', metavar='BAG',
                        help='where to read the scans (default: the recording named in '
                             'RUN/summary.json); a `replay --record` recording works too')
    parser.add_argument('--scan-topic', help='LaserScan topic of --recording (default: the '
                                             "replay's, or the only one)")
    parser.add_argument('--start', type=float, default=0.0, metavar='S',
                        help='start, seconds after the first scan (default 0)')
    parser.add_argument('--end', type=float, default=None, metavar='S',
                        help='end, seconds after the first scan (default: 30 s after --start)')
    parser.add_argument('--fps', type=float, default=10.0,
                        help='frames per second of the animation (default 10)')
    parser.add_argument('--speed', type=float, default=1.0,
                        help='playback speed relative to real time (default 1)')
    parser.add_argument('--size', type=int, default=480, metavar='PX',
                        help='image side in pixels (default 480)')
    parser.add_argument('--view', type=float, default=8.0, metavar='M',
                        help='half-width of the view in metres (default 8)')
    parser.add_argument('--trail', type=float, default=TRAIL_S, metavar='S',
                        help=f'seconds of track history drawn behind each track (default '
                             f'{TRAIL_S:g})')
    parser.add_argument('--follow', action='store_true',
                        help="draw in the scanner's frame (default: the odometry frame)")


@dataclass
class Run:
    """What an animation needs of a replay output."""

    ego_stamps: np.ndarray      # (S,) scans with a pose
    ego_poses: np.ndarray       # (S, 3) scanner poses, odometry frame
    stamp: np.ndarray           # confirmed track rows
    track_id: np.ndarray
    xy: np.ndarray
    vxy: np.ndarray
    kind: np.ndarray


def read_run(folder: Path) -> Run:
    """The poses and confirmed tracks of a replay folder (one-line errors for bad files)."""
    from laser_tracker.tools.evaluate import TRACK_COLUMNS, _read_csv, _track_row, read_replay

    replay = read_replay(folder)
    rows = [r for r in _read_csv(folder / 'tracks.csv', TRACK_COLUMNS + ('kind',),
                                 lambda r: (*_track_row(r[:-1]), r[-1] or 'object')) if r[7]]
    cols = list(zip(*rows)) if rows else [()] * 9
    order = np.argsort(replay.ego_stamps, kind='stable')
    return Run(replay.ego_stamps[order], replay.ego_poses[order], np.asarray(cols[0], float),
               np.asarray(cols[1], np.int64),
               np.column_stack((cols[2], cols[3])).reshape(-1, 2).astype(float),
               np.column_stack((cols[4], cols[5])).reshape(-1, 2).astype(float),
               np.asarray(cols[8], dtype=object))


def scans_source(args, folder: Path) -> tuple[Path, str]:
    """The recording and LaserScan topic to read the scans from (one-line errors)."""
    from laser_tracker.tools.bag import resolve_bag, scan_topics, topics

    summary = {}
    if (folder / 'summary.json').is_file():
        try:
            summary = json.loads((folder / 'summary.json').read_text())
        except ValueError as exc:
            raise InputFileError(folder / 'summary.json', f'not JSON: {exc}') from None
    if args.recording:
        bag = resolve_bag(args.recording)
    elif summary.get('bag'):
        bag = resolve_bag(summary['bag'])
    else:
        raise InputFileError(folder, 'no summary.json naming the replayed recording: give '
                             'the recording with --recording BAG')
    found = scan_topics(bag)
    if not found:
        have = ', '.join(f'{t} ({typ})' for t, (typ, _) in sorted(topics(bag).items()))
        raise InputFileError(bag, f'has no LaserScan topic to animate (it has: '
                             f'{have or "nothing"})')
    wanted = args.scan_topic or (summary.get('scan_topic') if not args.recording else None)
    if wanted in found:
        return bag, wanted
    if wanted and args.scan_topic:
        raise InputFileError(bag, f'no LaserScan topic {wanted} (LaserScan topics: '
                             f'{", ".join(found)})')
    if len(found) > 1:
        raise InputFileError(bag, f'has several LaserScan topics ({", ".join(found)}): name '
                             'one with --scan-topic')
    return bag, found[0]


def frame_scans(run: Run, start: float, end: float | None, fps: float, speed: float):
    """Indices into ``run.ego_stamps`` of the scan shown at each frame: the last scan at or
    before each frame time, frames ``speed / fps`` seconds of recording apart."""
    t0 = float(run.ego_stamps[0])
    first = t0 + start
    last = min(float(run.ego_stamps[-1]), t0 + (end if end is not None else start + 30.0))
    if last < first:
        raise LaserTrackerError(f'--start {start:g} s: the replay covers only '
                                f'{run.ego_stamps[-1] - t0:.1f} s')
    times = np.arange(first, last + 1e-9, speed / fps)
    index = np.searchsorted(run.ego_stamps, times + 1e-6, side='right') - 1
    return times, np.maximum(index, 0)


def read_scan_points(bag: Path, topic: str, stamps: np.ndarray) -> dict[float, np.ndarray]:
    """End points (scanner frame) of the scans whose header stamps are among ``stamps``
    (within 1e-4 s, the CSV's precision), keyed by that stamp."""
    from laser_tracker.conversions import scan_from_msg
    from laser_tracker.core.scan import ScanError
    from laser_tracker.tools.bag import iter_messages
    from laser_tracker.tools.scoring import match_stamps

    wanted = np.unique(stamps)
    found = {}
    for _, _, msg in iter_messages(bag, [topic]):
        try:
            scan = scan_from_msg(msg)
        except ScanError:
            continue
        k = int(match_stamps(np.array([scan.stamp]), wanted, 1e-4)[0])
        if k >= 0:
            found[float(wanted[k])] = scan.points()
    return found


def render(run: Run, times, index, points, args, t0: float):
    """The frames as RGB arrays."""
    from laser_tracker.conversions import KIND_COLOURS
    from laser_tracker.tools.annotations import from_frame, rotate_into, to_frame
    from laser_tracker.tools.figures import pyplot

    plt = pyplot()
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

    side = args.size / 100.0
    fig = plt.figure(figsize=(side, side), dpi=100)
    ax = fig.add_axes((0, 0, 1, 1))
    frames = []
    view = float(args.view)
    bar = 1.0 if view <= 4 else (2.0 if view <= 10 else 5.0)
    try:
        for t, k in zip(times, index):
            ax.cla()
            pose = run.ego_poses[k]
            stamp = run.ego_stamps[k]
            scan = points.get(int(k), np.zeros((0, 2)))
            here = run.stamp == stamp
            trail = (run.stamp <= stamp + 1e-6) & (run.stamp >= stamp - args.trail) & \
                np.isin(run.track_id, run.track_id[here])
            xy, vxy = run.xy, run.vxy
            if args.follow:         # odometry frame -> this scan's frame
                poses = np.repeat(pose[None, :], run.stamp.size, axis=0)
                xy = np.column_stack(from_frame(poses, xy[:, 0], xy[:, 1]))
                vxy = np.column_stack(rotate_into(poses, vxy[:, 0], vxy[:, 1]))
                centre = np.array([0.5 * view, 0.0])
            else:
                one = np.repeat(pose[None, :], scan.shape[0], axis=0)
                scan = np.column_stack(to_frame(one, scan[:, 0], scan[:, 1]))
                centre = pose[:2] + 0.5 * view * np.array([math.cos(pose[2]),
                                                           math.sin(pose[2])])
            ax.plot(scan[:, 0], scan[:, 1], '.', color='0.35', ms=2.0)
            heading = pose[2] if not args.follow else 0.0
            sx, sy = (0.0, 0.0) if args.follow else pose[:2]
            ax.plot(sx, sy, marker=(3, 0, math.degrees(heading) - 90), color='black', ms=9)
            for tid in np.unique(run.track_id[trail]):
                mine = trail & (run.track_id == tid)
                now = np.flatnonzero(mine & here)
                if not now.size:
                    continue
                j = now[-1]
                colour = KIND_COLOURS.get(str(run.kind[j]), (0.5, 0.5, 0.5))
                rows = np.flatnonzero(mine)
                rows = rows[np.argsort(run.stamp[rows], kind='stable')]
                ax.plot(xy[rows, 0], xy[rows, 1], '-', color=colour, lw=1.5, alpha=0.6)
                ax.plot(*xy[j], 'o', color=colour, ms=7)
                ax.arrow(*xy[j], *vxy[j], color=colour, width=0.03, head_width=0.18,
                         length_includes_head=True)
                ax.annotate(str(int(tid)), xy[j], xytext=(5, 5), textcoords='offset points',
                            color=colour, fontsize=10, fontweight='bold')
            ax.set_xlim(centre[0] - view, centre[0] + view)
            ax.set_ylim(centre[1] - view, centre[1] + view)
            ax.set_aspect('equal')
            ax.set_xticks([])
            ax.set_yticks([])
            ax.text(0.02, 0.97, f't = {t - t0:.1f} s', transform=ax.transAxes, va='top',
                    family='monospace', fontsize=10)
            ax.text(0.98, 0.97, 'person', color=KIND_COLOURS['person'], ha='right', va='top',
                    transform=ax.transAxes, fontsize=9, fontweight='bold')
            ax.text(0.98, 0.92, 'object', color=KIND_COLOURS['object'], ha='right', va='top',
                    transform=ax.transAxes, fontsize=9, fontweight='bold')
            ax.add_artist(AnchoredSizeBar(ax.transData, bar, f'{bar:g} m', 'lower left',
                                          frameon=False, size_vertical=view / 150))
            fig.canvas.draw()
            frames.append(np.asarray(fig.canvas.buffer_rgba())[..., :3].copy())
    finally:
        plt.close(fig)
    return frames


def write_animation(frames, path: Path, fps: float) -> Path:
    """GIF (Pillow) or, for ``.mp4``, H.264 through ffmpeg; atomically."""
    from laser_tracker.tools.atomic import atomic_path

    suffix = path.suffix.lower()
    with atomic_path(path, overwrite=True) as tmp:
        if suffix == '.mp4':
            ffmpeg = shutil.which('ffmpeg')
            h, w = frames[0].shape[:2]
            cmd = [ffmpeg, '-loglevel', 'error', '-y', '-f', 'rawvideo', '-pix_fmt', 'rgb24',
                   '-s', f'{w}x{h}', '-r', f'{fps:g}', '-i', '-', '-pix_fmt', 'yuv420p',
                   '-vf', 'pad=ceil(iw/2)*2:ceil(ih/2)*2', '-f', 'mp4', str(tmp)]
            done = subprocess.run(cmd, input=b''.join(f.tobytes() for f in frames),
                                  capture_output=True)
            if done.returncode != 0:
                raise LaserTrackerError(f'{path}: ffmpeg failed: '
                                        f'{done.stderr.decode(errors="replace").strip()}')
        else:
            from PIL import Image

            images = [Image.fromarray(f).quantize(colors=32, dither=Image.Dither.NONE)
                      for f in frames]
            with tmp.open('wb') as fh:
                images[0].save(fh, format='GIF', save_all=True, append_images=images[1:],
                               duration=int(round(1000.0 / fps)), loop=0, optimize=True)
    return path


def run(args: argparse.Namespace) -> int:
    folder = Path(args.run)
    out = Path(args.out) if args.out else folder / 'animation.gif'
    if out.suffix.lower() not in ('.gif', '.mp4'):
        raise LaserTrackerError(f'{out}: the animation is a .gif or an .mp4')
    if out.suffix.lower() == '.mp4' and shutil.which('ffmpeg') is None:
        raise LaserTrackerError(f'{out}: an MP4 needs ffmpeg on the PATH; write a .gif '
                                'instead')
    for name, value in (('--fps', args.fps), ('--speed', args.speed), ('--view', args.view)):
        if not value > 0:
            raise LaserTrackerError(f'{name} must be positive, got {value:g}')
    if not 64 <= args.size <= 4096:
        raise LaserTrackerError(f'--size {args.size}: expected 64 to 4096 pixels')
    data = read_run(folder)
    bag, topic = scans_source(args, folder)
    times, index = frame_scans(data, args.start, args.end, args.fps, args.speed)
    by_stamp = read_scan_points(bag, topic, data.ego_stamps[index])
    points = {int(k): by_stamp[float(data.ego_stamps[k])] for k in np.unique(index)
              if float(data.ego_stamps[k]) in by_stamp}
    needed = np.unique(index).size
    if len(points) < 0.9 * needed:
        raise InputFileError(bag, f'{needed - len(points)} of the {needed} scans to show are '
                             f'not on {topic} (by header stamp): was the run in {folder} '
                             'replayed from this recording?')
    frames = render(data, times, index, points, args, float(data.ego_stamps[0]))
    write_animation(frames, out, args.fps)
    print(f'{out}: {len(frames)} frames at {args.fps:g} fps '
          f'({out.stat().st_size / 1e6:.2f} MB), scans of {bag} {topic}')
    return 0
