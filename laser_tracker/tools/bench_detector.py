"""``laser-tracker bench detector``: speed and accuracy of the person detector (legs).

Speed: milliseconds per scan of ``PersonDetector.detect`` (segmentation, features, numpy tree
inference, pairing), median and 95th percentile, single-threaded, on real scans: 361 beams
(SICK LMS, CARMEN ``mit-csail.clf``), 245 beams (``person_following_outdoor_1``), 512 beams
(``demo_stationary_simple_environment``), 768 beams (leg_tracker training scans) and 1,081
beams (those 768-beam scans resampled to 0.25 degree, the geometry of a 270-degree Hokuyo
UTM). Scans come from the public data folder (``laser_tracker.tools.data.real_data()``);
recordings that are absent are skipped. ``--with-pipeline`` also times the motion pipeline
(as ``laser-tracker bench pipeline``) on a bundled 361-beam recording and the detector on the
same scans, and prints the scans per second of both together.

Accuracy (the recordings below are never used for training):

* ``person_following_outdoor_1``: the followed person is annotated (``/ground_truth_people_
  tracks``, scanner frame; an annotation belongs to the last scan received before it). Per
  annotation: is there a person detection within 0.5 m, within 0.75 m (recall); per
  annotated scan: how many other person detections (unlabelled: passers-by and clutter).
  Also on the scans resampled to 0.5 and 1 degree between beams.
* ``demo_stationary_simple_environment``: no labels; person detections per scan.
"""
from __future__ import annotations

import argparse
import gc
import logging
import time

import numpy as np

from laser_tracker.core.person_detector import PersonDetector, PersonDetectorConfig, load_model
from laser_tracker.core.scan import Scan, ScanError

FOLLOWING = 'leg_tracker/person_following_outdoor_1.bag'
FOLLOWING_SCAN = '/scan_base2'
FOLLOWING_TRUTH = '/ground_truth_people_tracks'
DEMO = 'leg_tracker/demo_stationary_simple_environment.bag'
TRAINING_GLOB = 'leg_tracker/training/positive_*_extracted.bag'
NEGATIVE = 'leg_tracker/training/negative_2.bag'
SICK = 'carmen/mit-csail.clf'
RADII = (0.5, 0.75)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--model', default='', metavar='NPZ',
                        help='model file (default: the packaged model)')
    parser.add_argument('--scans', type=int, default=1000,
                        help='scans timed per scanner type (default 1000)')
    parser.add_argument('--no-speed', action='store_true', help='skip the speed figures')
    parser.add_argument('--no-accuracy', action='store_true',
                        help='skip the recall / detections figures')
    parser.add_argument('--with-pipeline', action='store_true',
                        help='also time the motion pipeline on a bundled 361-beam recording '
                        'and report both together')
    parser.add_argument('--pair-distance', type=float,
                        help='override person_detector.pair_distance (m)')
    parser.add_argument('--json', metavar='PATH', help='also write the figures as JSON')


# ---------------------------------------------------------------------------- recordings


def read_scans(relative: str, topic: str | None = None, limit: int | None = None) -> list[Scan]:
    """Scans of a recording of the data folder ([] if absent); CARMEN logs too."""
    from laser_tracker.tools.data import real_recording

    path = real_recording(relative)
    if not path.exists():
        return []
    if path.suffix in ('.clf', '.log', '.gz'):
        from laser_tracker.tools.carmen import read_carmen

        log = read_carmen(path)
        return list(log.scans())[:limit]
    from laser_tracker.conversions import scan_from_msg
    from laser_tracker.tools.bag import iter_messages, topics

    names = [topic] if topic else [t for t, (k, _) in topics(path).items()
                                   if k == 'sensor_msgs/msg/LaserScan']
    out = []
    for _, _, msg in iter_messages(path, names):
        try:
            out.append(scan_from_msg(msg))
        except ScanError:
            continue
        if limit and len(out) >= limit:
            break
    return out


def speed_sets(limit: int) -> dict[str, list[Scan]]:
    import glob

    from laser_tracker.tools.data import real_recording
    from laser_tracker.tools.train_detector import resample

    sets = {}
    sick = read_scans(SICK, limit=limit)
    hokuyo = []
    for path in sorted(glob.glob(str(real_recording(TRAINING_GLOB)))):
        hokuyo += read_scans(str(path), '/training_scan')
    hokuyo += read_scans(NEGATIVE, limit=max(0, limit - len(hokuyo)))
    hokuyo = hokuyo[:limit]
    if sick:
        sets['361 beams (SICK LMS, mit-csail)'] = sick
    elif hokuyo:
        sets['361 beams (768-beam scans at 0.5 deg, 180 deg)'] = [
            _crop(resample(s, np.radians(0.5)), np.pi) for s in hokuyo]
    following = read_scans(FOLLOWING, FOLLOWING_SCAN, limit=limit)
    if following:
        sets['245 beams (person_following)'] = following
    demo = read_scans(DEMO, limit=limit)
    if demo:
        sets['512 beams (demo_stationary)'] = demo
    if hokuyo:
        sets['768 beams (leg_tracker training)'] = hokuyo
        sets['1081 beams (768-beam scans at 0.25 deg)'] = [resample(s, np.radians(0.25))
                                                          for s in hokuyo]
    if not sets:            # no public data: the synthetic room of `bench pipeline`
        from laser_tracker.tools.bench_pipeline import synthetic

        sets['361 beams (synthetic room, no public data found)'] = [
            e[1] for e in synthetic(min(limit, 200)).events if e[0] == 'scan']
    return sets


def _crop(scan: Scan, fov: float) -> Scan:
    """The central ``fov`` radians of a scan."""
    n = round(fov / abs(scan.angle_increment)) + 1
    first = max(0, (scan.n_beams - n) // 2)
    return Scan(stamp=scan.stamp, ranges=scan.ranges[first:first + n],
                angle_min=scan.angle_min + first * scan.angle_increment,
                angle_increment=scan.angle_increment, range_min=scan.range_min,
                range_max=scan.range_max, frame_id=scan.frame_id)


def time_detector(detector: PersonDetector, scans: list[Scan], repeat: int = 3) -> dict:
    """Per-scan wall time of ``detect`` and of its stages, segmentation with features and
    tree inference (fastest of ``repeat`` passes per scan; garbage collection paused)."""
    from laser_tracker.core.segmentation import segments_of

    stages = {
        'detect': detector.detect,
        'segment': lambda s: segments_of(s, detector.segments, detector.config.max_range),
    }
    features = [stages['segment'](s).features for s in scans]
    for s in scans[:50]:
        detector.detect(s)
    best = {name: np.full(len(scans), np.inf) for name in (*stages, 'trees')}
    gc.collect()
    gc.disable()
    try:
        for _ in range(repeat):
            for i, s in enumerate(scans):
                for name, f in stages.items():
                    t0 = time.perf_counter()
                    f(s)
                    best[name][i] = min(best[name][i], time.perf_counter() - t0)
                t0 = time.perf_counter()
                detector.classifier.predict_proba(features[i])
                best['trees'][i] = min(best['trees'][i], time.perf_counter() - t0)
    finally:
        gc.enable()
    ms = 1e3 * best['detect']
    return {'scans': len(scans), 'median_ms': float(np.median(ms)),
            'p95_ms': float(np.percentile(ms, 95)), 'mean_ms': float(ms.mean()),
            'scans_per_s': float(1e3 / ms.mean()),
            'segment_median_ms': float(np.median(1e3 * best['segment'])),
            'trees_median_ms': float(np.median(1e3 * best['trees'])),
            'clusters_per_scan': float(np.mean([f.shape[0] for f in features]))}


def pipeline_share(detector: PersonDetector, n_scans: int) -> dict | None:
    """The motion pipeline (``laser-tracker bench pipeline``) and the detector timed on the
    same bundled 361-beam recording, one after the other: the detector's share and the
    scans per second of both together."""
    from laser_tracker.core.pipeline import PipelineConfig
    from laser_tracker.tools.bench_pipeline import DEFAULT_BAGS, load_bag, timed_run

    try:
        events = load_bag(DEFAULT_BAGS[0])
    except Exception:  # noqa: BLE001 - a missing bundled recording only skips this figure
        return None
    pipe = timed_run(events, PipelineConfig(), n_scans)
    pipe_ms = 1e3 * pipe['wall'] / pipe['scans']
    scans = [e[1] for e in events.events if e[0] == 'scan']
    det = time_detector(detector, scans, repeat=1)
    return {'recording': events.name, 'beams': scans[0].n_beams, 'pipeline_ms': pipe_ms,
            'detector_ms': det['mean_ms'],
            'together_scans_per_s': 1e3 / (pipe_ms + det['mean_ms'])}


# ---------------------------------------------------------------------------- accuracy


def following_frames() -> list[tuple[Scan, np.ndarray]]:
    """(scan, annotations (a, 2)) for each scan of person_following that has annotations."""
    from laser_tracker.conversions import scan_from_msg
    from laser_tracker.tools.bag import iter_messages
    from laser_tracker.tools.data import real_recording

    path = real_recording(FOLLOWING)
    if not path.exists():
        return []
    frames: list[list] = []
    for topic, _, msg in iter_messages(path, [FOLLOWING_SCAN, FOLLOWING_TRUTH]):
        if topic == FOLLOWING_SCAN:
            try:
                frames.append([scan_from_msg(msg), []])
            except ScanError:
                frames.append([None, []])
        elif frames and frames[-1][0] is not None:
            frames[-1][1].append((msg.pose.position.x, msg.pose.position.y))
    return [(s, np.array(a, dtype=float)) for s, a in frames if s is not None and a]


def score_following(detector: PersonDetector, frames, increment: float | None = None) -> dict:
    from laser_tracker.tools.train_detector import resample

    hits = {r: 0 for r in RADII}
    others, annotations = [], 0
    for scan, truth in frames:
        if increment is not None:
            scan = resample(scan, increment)
        det = detector.detect(scan)
        annotations += truth.shape[0]
        if det.count == 0:
            others.append(0)
            continue
        d = np.hypot(*(truth[:, None, :] - det.xy[None, :, :]).transpose(2, 0, 1))
        for r in RADII:
            hits[r] += int((d.min(axis=1) <= r).sum())
        others.append(int((d.min(axis=0) > max(RADII)).sum()))
    others = np.array(others)
    return {'annotated_scans': len(frames), 'annotations': annotations,
            **{f'recall_{r}m': hits[r] / max(1, annotations) for r in RADII},
            'other_detections_per_scan': float(others.mean()) if others.size else 0.0}


def score_demo(detector: PersonDetector, scans: list[Scan]) -> dict:
    counts, legs = [], []
    for s in scans:
        det = detector.detect(s)
        counts.append(det.count)
        legs.append(int(det.is_leg.sum()))
    counts = np.array(counts)
    return {'scans': len(scans), 'detections_per_scan': float(counts.mean()),
            'legs_per_scan': float(np.mean(legs)),
            'share_of_scans_with': {str(k): float((counts == k).mean()) for k in range(3)} |
            {'3+': float((counts >= 3).mean())}}


# ---------------------------------------------------------------------------------- run


def run(args: argparse.Namespace) -> int:
    from laser_tracker.tools.atomic import check_output, write_json

    logging.basicConfig(level=logging.ERROR)
    if args.json:
        check_output(args.json, overwrite=True)
    changes = {'model': args.model}
    if args.pair_distance is not None:
        changes['pair_distance'] = args.pair_distance
    config = PersonDetectorConfig(**changes)
    classifier = load_model(config.model)
    detector = PersonDetector(config, classifier)
    print(f'person detector: model {classifier.path} ({classifier.n_trees} trees of depth '
          f'{classifier.depth}), leg threshold {detector.threshold:.3f}, pair distance '
          f'{config.pair_distance} m')
    report: dict = {'model': classifier.path, 'threshold': detector.threshold,
                    'config': config.__dict__}
    if not args.no_speed:
        print('\nspeed per scan (segmentation + features + trees + pairing), one core, '
              'fastest of 3 passes per scan; stages: median ms')
        print(f'{"scans":42s} {"n":>5s} {"median ms":>9s} {"p95 ms":>7s} {"scans/s":>7s} '
              f'{"segment":>7s} {"trees":>6s} {"clusters":>8s}')
        report['speed'] = {}
        for name, scans in speed_sets(args.scans).items():
            r = time_detector(detector, scans)
            report['speed'][name] = r
            print(f'{name:42s} {r["scans"]:5d} {r["median_ms"]:9.3f} {r["p95_ms"]:7.3f} '
                  f'{r["scans_per_s"]:7.0f} {r["segment_median_ms"]:7.3f} '
                  f'{r["trees_median_ms"]:6.3f} {r["clusters_per_scan"]:8.1f}')
        if args.with_pipeline:
            r = pipeline_share(detector, args.scans)
            report['with_pipeline'] = r
            if r is None:
                print('\nno bundled recording for the pipeline comparison')
            else:
                print(f'\nmotion pipeline {r["pipeline_ms"]:.3f} ms + person detector '
                      f'{r["detector_ms"]:.3f} ms per scan on {r["recording"]} '
                      f'({r["beams"]} beams): {r["together_scans_per_s"]:.0f} scans/s '
                      'together')
    if not args.no_accuracy:
        frames = following_frames()
        if frames:
            print('\nperson_following_outdoor_1 (245 beams, followed person annotated)')
            print(f'{"resolution":12s} {"annotations":>11s} {"recall 0.5 m":>12s} '
                  f'{"recall 0.75 m":>13s} {"other det./scan":>15s}')
            report['person_following'] = {}
            for label, inc in (('recorded', None), ('0.5 deg', np.radians(0.5)),
                               ('1 deg', np.radians(1.0))):
                r = score_following(detector, frames, inc)
                report['person_following'][label] = r
                print(f'{label:12s} {r["annotations"]:11d} {r["recall_0.5m"]:12.3f} '
                      f'{r["recall_0.75m"]:13.3f} {r["other_detections_per_scan"]:15.2f}')
        else:
            print(f'\n{FOLLOWING} not found: skipped')
        demo = read_scans(DEMO)
        if demo:
            r = score_demo(detector, demo)
            report['demo_stationary'] = r
            share = ', '.join(f'{k}: {v:.2f}' for k, v in r['share_of_scans_with'].items())
            print(f'\ndemo_stationary_simple_environment (512 beams, no labels): '
                  f'{r["detections_per_scan"]:.2f} person detections per scan over '
                  f'{r["scans"]} scans; share of scans with n detections {share}')
        else:
            print(f'\n{DEMO} not found: skipped')
    if args.json:
        write_json(args.json, report)
    return 0
