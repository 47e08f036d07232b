"""``laser-tracker replay BAG``: ego-motion, detection and tracking over a whole recording.

Runs :class:`laser_tracker.core.pipeline.Pipeline` on the scans and odometry of a rosbag2
folder or a ROS 1 bag (or a bundled recording's name) in receive order, as fast as the
machine allows (progress bar on stderr), exactly as the node graph would: scans wait for
their odometry by the recording's receive times (``odom_wait``), every stage applies its own
stream rules. It writes into ``--out DIR``:

* ``ego_motion.csv``: ``stamp,x,y,theta``, the scanner pose in the odometry frame per scan;
* ``tracks.csv``: ``stamp,track_id,x,y,vx,vy,weight,confirmed,kind,moving``, one row per
  hypothesis per scan, positions and velocities in the odometry frame (``confirmed`` and
  ``moving`` are 0/1);
* ``summary.json``: scans, scans skipped with their reasons, the scans of a fast scanner
  that detection left out (``scans_thinned``, ``difference.max_scan_rate``: they have
  poses only), the scanner's range noise near the robot (``range_noise``, m, as the
  self-mask measured it), every stage's counted events, messages stamped with their receive
  time (no header stamp), hypotheses created, confirmed tracks, ego-motion sources, the
  scanner mount used, timing, the configuration used;
* ``tracks.png`` (paper Fig. 10) and, with ``--figure-scan K``, ``scan_K.png`` (Fig. 5 / 7).

Configuration: ``--config FILE`` (repeatable, later files win) is read by the package's one
loader (``laser_tracker.parameters``), as the nodes read it: every node parameter that shapes
the result is honoured (``odom_wait`` included), and an unknown node or parameter, or a bad
value, is a one-line error. The scanner mount (base -> scanner) comes from the recording's
``/tf_static`` / ``/tf`` when it has them (said so on stderr; a scanner hung upside down has
its scans turned over, ``tools.mount``, ``ego_motion.mount_upside_down``, which a parameter
file may also set); a recording whose scan frame differs from its
odometry's child frame with no known mount gets a warning.

``--scan-topic`` must be a LaserScan topic of the recording and a given ``--odom-topic`` an
Odometry topic (a relative name means ``/name``); otherwise the error lists the recording's
topics of that type. A recording without an Odometry topic takes its odometry from ``/tf``
when that carries the transform from the odometry frame (the ego_motion node's
``odom_frame``, ``odom``) to the frame the scanner hangs from (REP 105, as ROS 1 trackers
read it); without either it runs on scan matching alone (said once).
A new ``--out`` folder is removed again when the replay fails or is interrupted. Bad input
never stops the replay: malformed scans and odometry are skipped and counted (one line per
reason at the end, no floods); a damaged recording ends the replay at the damage with the
outputs written and the reason in the summary.

``replay_bag`` is the API the ``evaluate`` and ``demo`` commands use.
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import logging
import math
import sys
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path

import numpy as np

from laser_tracker import parameters
from laser_tracker.conversions import odometry_from_msg, scan_from_msg, transforms_from_msg
from laser_tracker.core import jit
from laser_tracker.core.pipeline import STAGES, Pipeline, PipelineConfig
from laser_tracker.core.scan import ScanError
from laser_tracker.errors import InputFileError
from laser_tracker.tools.atomic import (atomic_path, check_output, removed_on_failure,
                                        write_json)
from laser_tracker.tools.bag import resolve_bag, stamp_if_unstamped

log = logging.getLogger(__name__)

EGO_HEADER = 'stamp,x,y,theta\n'
TRACKS_HEADER = 'stamp,track_id,x,y,vx,vy,weight,confirmed,kind,moving\n'
TRACKS_FIGURE = 'tracks.png'


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('bag', metavar='BAG', help='a rosbag2 folder, a ROS 1 .bag file, or '
                        'the name of a bundled recording')
    parser.add_argument('--config', metavar='YAML', action='append', default=[],
                        help='ROS parameter file (repeatable; default: the package defaults, '
                        'as in config/laser_tracker.yaml)')
    parser.add_argument('--namespace', metavar='NS',
                        help='namespace the nodes would run in, for parameter files with '
                        'namespaced keys (default: any)')
    parser.add_argument('--out', metavar='DIR', help='output folder (default out/<bag name>)')
    parser.add_argument('--scan-topic', default='/scan', help='LaserScan topic (default /scan)')
    parser.add_argument('--odom-topic',
                        help='Odometry topic (default /odom when the recording has it, else '
                        'the odom -> base transforms on /tf when it has them, else scan '
                        'matching alone)')
    parser.add_argument('--figure-scan', type=int, metavar='K',
                        help='also draw grid / previous grid / difference / velocities for '
                        'scan K (0-based)')
    parser.add_argument('--no-progress', action='store_true', help='no progress bar')
    rec = parser.add_argument_group('recording of the run (for Foxglove, RViz, animate)')
    rec.add_argument('--record', metavar='OUT',
                     help='also write a rosbag2 recording of the run: the scans, /tf, '
                          'ego-motion, grids, blobs, hypotheses, tracks and their markers, '
                          'ground truth')
    rec.add_argument('--record-storage', choices=('mcap', 'sqlite3'), default='mcap',
                     help='storage of the recording (default mcap, zstd-compressed)')
    rec.add_argument('--record-grids', default=None, metavar='every|none|N',
                     help='occupancy grid and difference map on every N-th scan (default '
                          f'{_default_grids()}), on every scan, or none')
    rec.add_argument('--evaluate', action='store_true',
                     help='add the evaluation per frame (/evaluation: matches, misses, false '
                          'positives) for a recording with ground truth or annotated people')
    rec.add_argument('--overwrite', action='store_true',
                     help='replace an existing recording at OUT')


def _default_grids() -> int:
    from laser_tracker.tools.record import DEFAULT_GRID_EVERY
    return DEFAULT_GRID_EVERY


def _record_options(args: argparse.Namespace):
    """The ``--record`` options (None without ``--record``); misuse is a one-line error."""
    from laser_tracker.errors import LaserTrackerError
    from laser_tracker.tools.record import RecordOptions, grid_every

    given = [name for name, value in (('--record-grids', args.record_grids),
                                      ('--evaluate', args.evaluate),
                                      ('--overwrite', args.overwrite)) if value]
    if not args.record:
        if given:
            raise LaserTrackerError(f'{", ".join(given)} only with --record OUT')
        return None
    grids = _default_grids() if args.record_grids is None else grid_every(args.record_grids)
    return RecordOptions(Path(args.record), args.record_storage, args.overwrite, grids,
                         args.evaluate)


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.WARNING, format='%(levelname)s %(name)s: %(message)s')
    bag = resolve_bag(args.bag)
    out = check_output(args.out or Path('out') / bag.name.removesuffix('.bag'), overwrite=True)
    node_params = parameters.load_files(args.config, namespace=args.namespace)
    record = _record_options(args)
    if record is not None and record.evaluate:
        _check_evaluable(bag)
    with removed_on_failure(out):
        summary = replay_bag(bag, config=node_params, out_dir=out, scan_topic=args.scan_topic,
                             odom_topic=args.odom_topic, progress=not args.no_progress,
                             figure_scan=args.figure_scan, record=record)
    skipped = sum(summary['scans_skipped'].values())
    thinned = summary['scans_thinned']
    used = (f'; detection used {summary["scans"]} of them, difference.max_scan_rate'
            if thinned else '')
    print(f'{summary["scans"] + thinned} scans replayed ({skipped} skipped{used}) in '
          f'{summary["timing"]["wall_s"]:.2f} s = {summary["timing"]["scans_per_s"] or 0:.0f} '
          f'scans/s; {summary["hypotheses_created"]} hypotheses created, '
          f'{summary["confirmed_tracks"]} confirmed tracks')
    for reason, count in summary['scans_skipped'].items():
        print(f'  skipped {count}: {reason}')
    for stage, events in summary['events'].items():
        for reason, count in sorted(events.items()):
            print(f'  {stage}: {reason}: {count}')
    print(f'outputs in {out}: ' + ', '.join(summary['files']))
    if record is not None:
        r = summary['recording']
        print(f'recording in {r["path"]}: {sum(r["messages"].values())} messages, '
              f'{r["bytes"] / 1e6:.2f} MB ({r["storage"]})')
    return 0


def _check_evaluable(bag: Path) -> None:
    """``--evaluate`` needs per-frame labels: refuse, before the replay, a recording that
    has none."""
    from laser_tracker.errors import InputFileError
    from laser_tracker.tools.evaluate import recording_kind

    if recording_kind(bag) not in ('simulated', 'annotated'):
        raise InputFileError(bag, '--evaluate needs a recording with ground truth '
                             '(/ground_truth) or annotated people (/ground_truth_people_tracks)'
                             '; record without --evaluate')


def _odometry_poses(msg, tf_odom) -> list[tuple[float, np.ndarray]]:
    """(stamp, pose) of the odometry in ``msg``: an Odometry message, or (``tf_odom``) the
    transforms ``odom_frame`` -> ``base_frame`` of a TFMessage."""
    if tf_odom is None:
        odo = odometry_from_msg(msg)
        return [(odo.stamp, odo.pose)]
    return [(t.stamp, np.array([t.x, t.y, t.yaw])) for t in transforms_from_msg(msg)
            if t.parent == tf_odom.odom_frame and t.child == tf_odom.base_frame]


def _note_unstamped(msg, topic: str, receive_ns: int, counts: Counter) -> None:
    """Stamp a message without a header stamp with its receive time, saying so once per
    topic (:func:`tools.bag.stamp_if_unstamped`)."""
    if stamp_if_unstamped(msg, receive_ns):
        if not counts[topic]:
            log.warning('%s carries no header stamp (0): each such message is stamped with '
                        'its receive time in the recording', topic)
        counts[topic] += 1


def _fmt(v: float) -> str:
    return f'{v:.6f}' if math.isfinite(v) else 'nan'


def _configuration(config) -> tuple[PipelineConfig, float, str, dict]:
    """(pipeline config, odom_wait, odom_frame, {node: {name: value}}) from what
    ``replay_bag`` accepts: None (defaults), a PipelineConfig, loaded node parameters, or a
    parameter file path."""
    if config is None or isinstance(config, (str, Path)):
        config = parameters.load_files([config] if config is not None else [])
    if isinstance(config, PipelineConfig):
        node = parameters.EgoMotionNodeConfig()
        return config, node.odom_wait, node.odom_frame, config.to_ros_params()
    pipeline = parameters.pipeline_config(config)
    node = config['ego_motion'].sections['']
    return (pipeline, node.odom_wait, node.odom_frame,
            {n: config[n].values() for n in parameters.REPLAY_NODES})


def replay_bag(bag_path, config=None, out_dir: Path | None = None,
               scan_topic: str = '/scan', odom_topic: str | None = None, progress: bool = True,
               figure_scan: int | None = None,
               on_confirmed: Callable[[float, int, float, float, float, float], None] | None
               = None, record=None) -> dict:
    """Replay a recording; return the summary dict (also written as ``summary.json``).

    ``config``: None (the defaults), a parameter file path, a PipelineConfig, or the result
    of ``parameters.load``. ``scan_topic`` and a given ``odom_topic`` must be topics of their
    type in the recording (InputFileError); without ``odom_topic``, ``/odom`` is used when the
    recording has it, else the odometry on ``/tf`` when it has that, else scan matching alone
    (said on stderr). Without ``out_dir`` nothing is written (the summary is still
    returned). ``on_confirmed(stamp, track_id, x, y, vx, vy)`` is called once per track, when
    it is first confirmed (odometry frame). ``record`` (``tools.record.RecordOptions``): also
    write a recording of the run; its output is checked before the replay starts.
    """
    if record is None:
        return _replay(bag_path, config, out_dir, scan_topic, odom_topic, progress,
                       figure_scan, on_confirmed)
    from laser_tracker.tools.record import RecordingProcess

    if record.evaluate and out_dir is None:
        raise ValueError('record.evaluate needs out_dir (the evaluation reads the outputs)')
    with RecordingProcess(record) as recorder:
        summary = _replay(bag_path, config, out_dir, scan_topic, odom_topic, progress,
                          figure_scan, on_confirmed, recorder)
        if record.evaluate:
            from laser_tracker.tools.evaluate import evaluate_recording

            ev = evaluate_recording(out_dir, summary['bag'], scan_topic=scan_topic)
            summary['recording_evaluation_frames'] = recorder.evaluation(ev)
    summary['recording'] = recorder.summary()
    if out_dir is not None:
        write_json(Path(out_dir) / 'summary.json', summary)
    return summary


def _replay(bag_path, config, out_dir, scan_topic, odom_topic, progress, figure_scan,
            on_confirmed, recorder=None) -> dict:
    """:func:`replay_bag`, feeding ``recorder`` (``tools.record.RecordingProcess``) when
    given."""
    from laser_tracker.tools.bag import (ODOM_TOPIC, ODOMETRY_MSGTYPE, SCAN_MSGTYPE,
                                         iter_messages, require_topic, topics)
    from laser_tracker.tools.mount import recording_mount, tf_odometry

    bag_path = resolve_bag(bag_path)
    config, odom_wait, odom_frame, node_values = _configuration(config)
    info = topics(bag_path)
    scan_topic = require_topic(bag_path, info, scan_topic, SCAN_MSGTYPE, '--scan-topic')
    given_odom_topic = odom_topic is not None
    if odom_topic is not None or ODOM_TOPIC in info:
        odom_topic = require_topic(bag_path, info, odom_topic or ODOM_TOPIC, ODOMETRY_MSGTYPE,
                                   '--odom-topic')
    wanted = [scan_topic]
    has_odometry = odom_topic is not None and info[odom_topic][1] > 0
    tf_odom = None
    if has_odometry:
        wanted.append(odom_topic)
    elif not given_odom_topic:
        tf_odom = tf_odometry(bag_path, scan_topic, odom_frame)
    if tf_odom is not None:
        wanted.append(tf_odom.topic)
        print(f'{bag_path.name}: no Odometry topic: odometry from {tf_odom.topic} '
              f'({tf_odom.odom_frame} -> {tf_odom.base_frame})', file=sys.stderr)
    elif not has_odometry:
        print(f'{bag_path.name}: no odometry on {odom_topic or ODOM_TOPIC}'
              + ('' if given_odom_topic else f' or {odom_frame!r} on /tf')
              + ': ego-motion from scan matching alone', file=sys.stderr)
    if out_dir is not None:           # an output that cannot be written fails before work
        out_dir = Path(out_dir)
        check_output(out_dir, overwrite=True)
        out_dir.mkdir(parents=True, exist_ok=True)
    mount = recording_mount(bag_path, scan_topic, odom_topic if has_odometry else None,
                            config.ego_motion, tf_odom.base_frame if tf_odom else None)
    if mount.from_recording:
        config = dataclasses.replace(config, ego_motion=dataclasses.replace(
            config.ego_motion, mount_x=mount.x, mount_y=mount.y, mount_yaw=mount.yaw,
            mount_upside_down=mount.mirrored))
    upside_down = config.ego_motion.mount_upside_down
    if mount.message:
        print(f'{bag_path.name}: {mount.message}', file=sys.stderr)
    n_scans = int(info[scan_topic][1])
    passthrough: set[str] = set()
    if recorder is not None:
        recorder.start(bag_path, info, scan_topic, dataclasses.replace(
            mount, mirrored=upside_down), config.grid.resolution)
        passthrough = set(recorder.passthrough_topics) - set(wanted)
        wanted += sorted(passthrough)

    pipeline = Pipeline(config, odom_wait=odom_wait, profile=True)
    skipped: Counter = Counter()
    confirmed_ids: set[int] = set()
    figure_rows: list[tuple] = []       # confirmed rows for Fig. 10
    scanner: list[tuple] = []
    files: list[str] = []
    odometry_messages = 0
    unstamped: Counter = Counter()     # topic -> messages stamped with their receive time
    skipped_odometry: Counter = Counter()
    damage = None
    scan_index = -1
    state = {'scans_done': 0, 'thinned': 0, 'background': None, 'figure': None}
    wall0 = time.perf_counter()

    with contextlib.ExitStack() as stack:
        if out_dir is not None:
            ego_f = stack.enter_context(atomic_path(out_dir / 'ego_motion.csv', True)).open('w')
            trk_f = stack.enter_context(atomic_path(out_dir / 'tracks.csv', True)).open('w')
            stack.callback(trk_f.close)
            stack.callback(ego_f.close)
            ego_f.write(EGO_HEADER)
            trk_f.write(TRACKS_HEADER)
        else:
            ego_f = trk_f = None
        bar = _progress(n_scans, progress, bag_path.name)
        stack.callback(bar.close)

        def process(results) -> None:
            for result in results:
                if result.thinned:
                    state['thinned'] += 1
                    continue
                if result.skipped:
                    skipped[result.skipped] += 1
                    continue
                state['scans_done'] += 1
                if state['background'] is None:
                    from laser_tracker.core.geometry import transform_points
                    state['background'] = transform_points(result.pose, result.scan.points())
                tracks = pipeline.tracker.tracks()
                _write_scan(result, tracks, ego_f, trk_f)
                if recorder is not None:
                    recorder.step(result, tracks)
                scanner.append(tuple(result.pose))
                h = result.hypotheses
                for j in np.flatnonzero(h.confirmed):
                    figure_rows.append((result.stamp, int(h.track_id[j]), *h.position[j],
                                        *h.velocity[j]))
                for j in result.newly_confirmed:
                    tid = int(h.track_id[j])
                    if tid in confirmed_ids:
                        continue
                    confirmed_ids.add(tid)
                    if on_confirmed is not None:
                        on_confirmed(float(result.stamp), tid, float(h.position[j, 0]),
                                     float(h.position[j, 1]), float(h.velocity[j, 0]),
                                     float(h.velocity[j, 1]))
                if result.stamp == state['figure'] and out_dir is not None:
                    from laser_tracker.tools.figures import scan_figure
                    name = f'scan_{figure_scan}.png'
                    scan_figure(result, config.grid.resolution, out_dir / name,
                                f'{bag_path.name}: scan {figure_scan} at t = '
                                f'{result.stamp:.3f} s')
                    files.append(name)

        try:
            for topic, t_ns, msg in iter_messages(bag_path, wanted):
                arrival = t_ns * 1e-9
                if topic in passthrough:
                    recorder.passthrough(topic, t_ns, msg)
                    continue
                if topic != scan_topic:
                    try:
                        if tf_odom is None:
                            _note_unstamped(msg, topic, t_ns, unstamped)
                        poses = _odometry_poses(msg, tf_odom)
                    except Exception as exc:   # noqa: BLE001 - any malformed message
                        skipped_odometry[f'malformed: {type(exc).__name__}'] += 1
                        continue
                    for stamp, pose in poses:
                        odometry_messages += 1
                        process(pipeline.add_odometry(stamp, pose, arrival))
                    continue
                scan_index += 1
                jit.raise_deferred_interrupt()     # a Ctrl-C numba's compiler held back
                bar.update(1)
                process(pipeline.poll(arrival))
                try:
                    _note_unstamped(msg, topic, t_ns, unstamped)
                    scan = scan_from_msg(msg)
                except (ScanError, ValueError, TypeError, AttributeError) as exc:
                    reason = f'malformed scan: {_generic(str(exc))}'
                    if not skipped[reason]:
                        log.warning('scan %d skipped: %s', scan_index, exc)
                    skipped[reason] += 1
                    continue
                want = figure_scan is not None and scan_index == figure_scan
                if want:
                    state['figure'] = scan.stamp
                if recorder is not None:     # the scan as the pipeline sees it (turned over)
                    recorder.scan_message(scan_index, msg,
                                          scan.mirrored() if upside_down else scan)
                    want = want or recorder.wants_grids(scan_index)
                process(pipeline.add_scan(scan, arrival, want))
            process(pipeline.flush())
        except InputFileError as exc:
            damage = str(exc)
            log.error('replay stopped early: %s', damage)
            process(pipeline.flush())
        wall = time.perf_counter() - wall0
        scans_done, background = state['scans_done'], state['background']

    if figure_scan is not None and not (0 <= figure_scan <= scan_index):
        log.warning('--figure-scan %d: the recording has scans 0..%d', figure_scan, scan_index)
    stats = pipeline.tracker.stats
    summary = {
        'bag': str(bag_path),
        'scan_topic': scan_topic,
        'odom_topic': odom_topic if has_odometry else None,
        'odom_tf': (f'{tf_odom.topic}: {tf_odom.odom_frame} -> {tf_odom.base_frame}'
                    if tf_odom else None),
        'scans': scans_done,
        'scan_messages': scan_index + 1,
        'scans_skipped': dict(skipped),
        'scans_thinned': state['thinned'],
        'odometry_messages': odometry_messages,
        'stamped_with_receive_time': dict(unstamped),
        'odometry_skipped': dict(skipped_odometry),
        'events': pipeline.events(),
        'hypotheses_created': int(stats['created']),
        'confirmed_tracks': len(confirmed_ids),
        'tracker': {k: int(v) for k, v in stats.items()},
        'ego_motion_sources': dict(pipeline.sources),
        'range_noise': pipeline.ego.self_mask.range_noise,
        'scanner_mount': {'x': config.ego_motion.mount_x, 'y': config.ego_motion.mount_y,
                          'yaw': config.ego_motion.mount_yaw, 'source': mount.source,
                          'mirrored': upside_down},
        'odom_wait': odom_wait,
        'timing': {
            'wall_s': wall,
            # every scan the pipeline took in: the ego-motion's too (a thinned scan has a
            # pose), the other stages' only those detection used
            'scans_per_s': (scans_done + state['thinned']) / wall if wall > 0 else None,
            'ms_per_scan': {s: 1e3 * pipeline.times[s] / max(
                scans_done + (state['thinned'] if s == 'ego_motion' else 0), 1)
                for s in STAGES},
        },
        'damaged': damage,
        'config': node_values,
    }
    if out_dir is not None:
        files[:0] = ['ego_motion.csv', 'tracks.csv']
        from laser_tracker.tools.figures import tracks_figure
        rows = np.array(figure_rows, float).reshape(-1, 6)
        tracks_figure(rows, np.array(scanner, float).reshape(-1, 3), out_dir / TRACKS_FIGURE,
                      f'{bag_path.name}: {len(confirmed_ids)} confirmed tracks with '
                      f'velocity (1 s of travel)', background=background)
        files.append(TRACKS_FIGURE)
        files.append('summary.json')
        summary['files'] = files
        write_json(out_dir / 'summary.json', summary)
    else:
        summary['files'] = []
    return summary


def _write_scan(result, tracks, ego_f, trk_f) -> None:
    if ego_f is None:
        return
    x, y, t = result.pose
    stamp = _fmt(result.stamp)
    ego_f.write(f'{stamp},{x:.6f},{y:.6f},{t:.6f}\n')
    if len(tracks):
        trk_f.writelines(
            f'{stamp},{int(i)},{p[0]:.4f},{p[1]:.4f},{v[0]:.4f},{v[1]:.4f},{w:.2f},{int(c)},'
            f'{k},{int(m)}\n'
            for i, p, v, w, c, k, m in zip(tracks.track_id, tracks.position, tracks.velocity,
                                           tracks.weight, tracks.confirmed, tracks.kind,
                                           tracks.moving))


def _generic(reason: str) -> str:
    """Group reasons that differ only in numbers (beam counts, stamps)."""
    import re
    text = re.sub(r'-?\d+(\.\d+)?(e-?\d+)?', '#', reason)
    return text if len(text) < 120 else text[:117] + '...'


def _progress(total: int, enabled: bool, name: str):
    try:
        from tqdm import tqdm
    except ImportError:  # tqdm is in the tools extra
        enabled = False
    if not enabled:
        class _Null:
            def update(self, n=1):
                pass

            def close(self):
                pass
        return _Null()
    return tqdm(total=total, unit='scan', file=sys.stderr, desc=name, leave=False,
                mininterval=0.2)
