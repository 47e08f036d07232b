"""``laser-tracker bench real``: the tracker on the public real recordings, scored.

Replays each real recording found under ``$LASER_TRACKER_DATA`` (README.md, "Data") with the
package defaults and with ``config/paper_reference.yaml`` (the paper's method alone), scores
the replay with ``laser-tracker evaluate`` and prints one table (and ``--json``):

* ``person_following``: leg_tracker's annotated person-following recording (no odometry):
  following-mode counts as the leg_tracker benchmarks count them, CLEAR MOT over every
  annotated person and over the walking ones;
* ``freiburg_realistic`` / ``freiburg_poor``: freiburg-079 part 1, imported with its
  SLAM-corrected poses as the reference and a noisy copy as odometry (two noise models):
  false tracks per minute on static structure;
* ``mit_csail``: the raw mit-csail log with its own odometry: false tracks per minute on
  static structure mapped with the replay's poses;
* ``leg_demo``: leg_tracker's stationary demo (people walking and standing, no labels):
  confirmed tracks per minute, by kind.

What is not present is reported as missing, never failed. It takes a few minutes.
"""
from __future__ import annotations

import argparse
import json
import logging
import tempfile
import time
from pathlib import Path

from laser_tracker import parameters
from laser_tracker.tools.atomic import check_output
from laser_tracker.tools.data import real_recording

REPO = Path(__file__).resolve().parents[2]
CONFIGS = {'defaults': None, 'paper': REPO / 'config' / 'paper_reference.yaml'}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--only', nargs='+', metavar='NAME',
                        help='person_following freiburg_realistic freiburg_poor mit_csail '
                             'leg_demo (default: all)')
    parser.add_argument('--modes', nargs='+', default=list(CONFIGS), choices=list(CONFIGS),
                        help='configurations to run (default: defaults paper)')
    parser.add_argument('--config', metavar='YAML', help='a parameter file to run as well '
                        '(mode "custom")')
    parser.add_argument('--json', metavar='OUT', help='write the figures as JSON')
    parser.add_argument('--keep', metavar='DIR', help='keep the replays here')


def _recordings(work: Path) -> dict:
    """name -> (bag, scan topic, static map mode) for what is available (importing logs)."""
    from laser_tracker.tools.import_carmen import convert

    found = {}
    pf = real_recording('leg_tracker/person_following_outdoor_1.bag')
    if pf.exists():
        found['person_following'] = (pf, '/scan_base2', None)
    freiburg = real_recording('carmen/freiburg-079-part1-corrected.log.gz')
    if freiburg.exists():
        for noise in ('realistic', 'poor'):
            out = work / f'freiburg_{noise}'
            if not out.exists():
                convert(freiburg, out, odometry_noise_model=noise, seed=0)
            found[f'freiburg_{noise}'] = (out, '/scan', 'reference')
    mit = real_recording('carmen/mit-csail.clf')
    if mit.exists():
        out = work / 'mit_csail'
        if not out.exists():
            convert(mit, out)
        found['mit_csail'] = (out, '/scan', 'ego')
    demo = real_recording('leg_tracker/demo_stationary_simple_environment.bag')
    if demo.exists():
        found['leg_demo'] = (demo, '/scan', None)
    return found


def score(name: str, bag: Path, scan_topic: str, static: str | None, config, out: Path) -> dict:
    """Replay ``bag`` into ``out`` with ``config`` and score it; the figures of the table."""
    from laser_tracker.tools.evaluate import evaluate_recording, report_unlabelled
    from laser_tracker.tools.replay import replay_bag

    t0 = time.perf_counter()
    summary = replay_bag(bag, config=config, out_dir=out, scan_topic=scan_topic,
                         progress=False)
    row = {'scans': summary['scans'], 'confirmed': summary['confirmed_tracks'],
           'replay_s': round(time.perf_counter() - t0, 1)}
    if name == 'person_following':
        ev = evaluate_recording(out, bag, scan_topic=scan_topic).result
        f = ev['following_all_annotations']
        row.update(tracked=f['tracked'], annotated=f['objects'], switches=f['id_switches'],
                   misses=f['misses'],
                   mota_all=ev['clear_mot']['all']['mota'],
                   mota_walking=ev['clear_mot']['walking']['mota'],
                   fp=ev['clear_mot']['all']['num_false_positives'])
    elif static is not None:
        st = evaluate_recording(out, bag, static=static, scan_topic=scan_topic)
        s = st.result['static_structure']
        row.update(minutes=round(s['duration_s'] / 60, 2), false=s['false_tracks'],
                   false_per_minute=s['false_per_minute'],
                   confirmed_per_minute=s['confirmed_per_minute'])
    else:
        r = report_unlabelled(out).result
        row.update(minutes=round(r['duration_s'] / 60, 2),
                   confirmed_per_minute=r['confirmed_per_minute'])
    kinds = _kinds(out / 'tracks.csv')
    row.update(kinds)
    return row


def _kinds(path: Path) -> dict:
    """Confirmed tracks by kind (person / object) and how many were ever standing."""
    import csv
    kind, standing = {}, set()
    with open(path, newline='') as fh:
        for r in csv.DictReader(fh):
            if r['confirmed'] != '1':
                continue
            kind[r['track_id']] = r.get('kind', 'object')
            if r.get('moving') == '0':
                standing.add(r['track_id'])
    return {'person_tracks': sum(1 for k in kind.values() if k == 'person'),
            'object_tracks': sum(1 for k in kind.values() if k != 'person'),
            'ever_standing': len(standing)}


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.ERROR)
    if args.json:
        check_output(args.json, overwrite=True)
    configs = {m: CONFIGS[m] for m in args.modes}
    if args.config:
        configs['custom'] = Path(args.config)
    with tempfile.TemporaryDirectory(prefix='laser_tracker_bench_real_') as tmp:
        work = Path(args.keep) if args.keep else Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        found = _recordings(work)
        names = args.only or ['person_following', 'freiburg_realistic', 'freiburg_poor',
                              'mit_csail', 'leg_demo']
        results: dict = {}
        for name in names:
            if name not in found:
                print(f'{name}: not found under $LASER_TRACKER_DATA (README.md, "Data")')
                continue
            bag, topic, static = found[name]
            for mode, path in configs.items():
                config = parameters.load_files([path] if path else [])
                row = score(name, bag, topic, static, config, work / f'{name}_{mode}')
                results.setdefault(name, {})[mode] = row
                print(f'{name:<20} {mode:<9} ' + ', '.join(
                    f'{k} {_fmt(v)}' for k, v in row.items()), flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2) + '\n')
    return 0


def _fmt(v) -> str:
    return f'{v:.3f}' if isinstance(v, float) else str(v)
