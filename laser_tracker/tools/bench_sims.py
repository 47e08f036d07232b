"""``laser-tracker bench sims``: the tracker on the bundled simulated recordings, scored.

Replays every bundled recording (``bags/``, made by the scenario simulator, with its true
objects) in the modes of ``bench real`` (``paper``, ``motion``, ``defaults``, and ``custom``
with ``--config``), scores each with ``laser-tracker evaluate`` and prints one row per
recording and mode (``--markdown`` for README.md, ``--json`` for programs): straight paths
detected, people detected among those passing, false detections, CLEAR MOT over the objects
in view (MOTA, false-positive frames, ID switches) and the median position error.

``--scan-rates 10 15 20 40`` also simulates the two scenarios of a Hokuyo-class scanner
(``driving_past_people``, ``hokuyo_corridor_lobby``) as scanners of those rates (the head
turning that fast, every revolution delivered) and scores them as rows ``NAME@RATEHz``;
``--range-noise 0.03 0.05`` as scanners of that range noise (m, one sigma), rows
``NAME@NOISEm``; ``--spurious 0.005 0.02`` as scanners that report that share of their beams
at a random range short of the surface (dust, a mixed pixel), rows ``NAME@SHAREspurious``;
``--scanner-360 5 10`` as a low-cost 360 deg scanner turning that fast (:data:`LOW_COST_360`),
rows ``NAME@360degRATEHz``; ``--beam-count-jitter 2 5`` as scanners whose beam count varies
by up to that many from scan to scan over the same field (drivers that publish each
revolution's samples as they came), rows ``NAME@NbeamsJitter``.
"""
from __future__ import annotations

import argparse
import json
import logging
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Callable, NamedTuple

from laser_tracker.tools.atomic import check_output
from laser_tracker.tools.bench_real import MODES, mode_parameters


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--only', nargs='+', metavar='NAME', help='bundled recordings '
                        '(default: all)')
    parser.add_argument('--modes', nargs='+', default=list(MODES), choices=list(MODES),
                        help='configurations to run (default: all three)')
    parser.add_argument('--config', metavar='YAML', action='append', default=[],
                        help='a parameter file to run as well (mode "custom")')
    parser.add_argument('--json', metavar='OUT', help='write the figures as JSON')
    parser.add_argument('--markdown', action='store_true', help='print a Markdown table')
    parser.add_argument('--jobs', type=int, default=1, help='replays run in parallel')
    for v in SCANNER_VARIANTS:
        parser.add_argument(v.option, nargs='+', type=v.kind, default=[], metavar=v.metavar,
                            help=v.help)


#: The scenarios of a Hokuyo-class scanner, whose head rate ``--scan-rates`` changes.
HOKUYO_SCENARIOS = ('driving_past_people', 'hokuyo_corridor_lobby')


#: A low-cost 360 deg scanner (the RPLidar A1 or LDS-01 class of small robots), as fields of
#: the simulated Hokuyo: 360 beams 1 deg apart, 12 m, 3 cm of range noise, every revolution
#: delivered.
LOW_COST_360 = {'beams': 360, 'steps_per_revolution': 360, 'range_max': 12.0,
                'noise_sigma': 0.03, 'skip': 0}


class ScannerVariant(NamedTuple):
    """A command-line option whose values are other scanners for the Hokuyo scenarios."""

    option: str
    kind: type
    metavar: str
    help: str
    suffix: Callable          # value -> the row's suffix (NAME@SUFFIX)
    fields: Callable          # value -> the simulated Hokuyo's fields it sets


#: The scanners the Hokuyo scenarios are also simulated as.
SCANNER_VARIANTS = tuple(ScannerVariant(*row) for row in (
    ('--scan-rates', float, 'HZ',
     'also the Hokuyo scenarios (%s) simulated as scanners of these rates, rows '
     'NAME@RATEHz' % ', '.join(HOKUYO_SCENARIOS),
     lambda rate: f'{rate:g}Hz', lambda rate: {'revolution_hz': rate, 'skip': 0}),
    ('--range-noise', float, 'M',
     'also the Hokuyo scenarios simulated as scanners of this range noise (m, one sigma; '
     'bundled: 0.01 and 0.015), rows NAME@NOISEm',
     lambda noise: f'{noise:g}m', lambda noise: {'noise_sigma': noise}),
    ('--spurious', float, 'SHARE',
     'also the Hokuyo scenarios simulated as scanners that report this share of their '
     'beams at a random range short of the surface (dust, a mixed pixel; bundled: 0.0005), '
     'rows NAME@SHAREspurious',
     lambda share: f'{share:g}spurious', lambda share: {'spurious_probability': share}),
    ('--scanner-360', float, 'HZ',
     'also the Hokuyo scenarios seen by a low-cost 360 deg scanner (360 beams 1 deg apart, '
     '12 m, 3 cm of range noise) turning at these rates, rows NAME@360degRATEHz',
     lambda rate: f'360deg{rate:g}Hz', lambda rate: dict(LOW_COST_360, revolution_hz=rate)),
    ('--beam-count-jitter', int, 'N',
     'also the Hokuyo scenarios seen by a scanner whose beam count varies by up to N from '
     'scan to scan over the same field (YDLIDAR\'s ROS 2 driver, RPLIDAR without '
     'angle_compensate), rows NAME@NbeamsJitter',
     lambda n: f'{n}beamsJitter', lambda n: {'beam_count_jitter': n}),
))


def other_scanners(args: argparse.Namespace) -> list[tuple[str, dict]]:
    """Per scanner the options ask for (in the order of :data:`SCANNER_VARIANTS`): its row
    suffix and the simulated Hokuyo's fields it sets."""
    return [(v.suffix(value), v.fields(value))
            for v in SCANNER_VARIANTS
            for value in getattr(args, v.option[2:].replace('-', '_'))]


def simulate_scanner(name: str, out: Path, **scanner) -> Path:
    """The scenario ``name`` seen by another scanner, written to ``out``: ``scanner`` names
    the fields of its :class:`~laser_tracker.tools.sim.lidar.HokuyoConfig` that differ
    (``revolution_hz`` with ``skip=0``: a scanner of that rate, every revolution delivered;
    ``noise_sigma``: of that range noise; ``spurious_probability``: reporting that share of
    its beams at a random range short of the surface; :data:`LOW_COST_360`)."""
    import dataclasses

    from laser_tracker.tools.sim.recorder import record
    from laser_tracker.tools.sim.scenarios import build
    from laser_tracker.tools.simulate import write_recording

    scenario = build(name)
    lidar = dataclasses.replace(scenario.lidar, **scanner)
    write_recording(record(dataclasses.replace(scenario, lidar=lidar)), out)
    return out


def score(name: str, mode: str, files, bag: Path | None = None) -> dict:
    """Replay bundled recording ``name`` (or the recording ``bag``) in ``mode`` and score
    it."""
    from laser_tracker.tools.bag import resolve_bag
    from laser_tracker.tools.evaluate import evaluate_replay
    from laser_tracker.tools.replay import replay_bag

    logging.basicConfig(level=logging.ERROR)
    bag = bag or resolve_bag(name)
    with tempfile.TemporaryDirectory(prefix='laser_tracker_bench_sims_') as tmp:
        replay_bag(bag, config=mode_parameters(mode, files), out_dir=Path(tmp), progress=False)
        r = evaluate_replay(Path(tmp), bag).result
    cm = r['clear_mot']['detectable']
    median = r['position_error']['median']
    return {'paths': r['paths_detected'], 'paths_taken': r['paths_taken'],
            'passing': r['objects_passing'], 'detected': r['objects_detected'],
            'false_detections': r['false_detections'],
            'false_positives': cm['num_false_positives'], 'switches': cm['num_switches'],
            'matches': cm['num_matches'], 'objects': cm['num_objects'],
            'mota': round(cm['mota'], 3) if cm['mota'] is not None else float('nan'),
            'median_error': round(median, 3) if median is not None else float('nan')}


def _job(job):
    name, mode, files, bag = job
    return name, mode, score(name, mode, files, bag)


def _simulate(job) -> Path:
    _, name, out, scanner = job
    return simulate_scanner(name, out, **scanner)


def run(args: argparse.Namespace) -> int:
    from laser_tracker.tools.bag import bundled_bags

    if args.json:
        check_output(args.json, overwrite=True)
    modes = list(args.modes) + (['custom'] if args.config else [])
    if args.config:
        mode_parameters('custom', args.config)      # a bad file fails before any work
    names = args.only or bundled_bags()
    jobs = [(name, mode, args.config, None) for name in names for mode in modes]
    results: dict = {}
    with tempfile.TemporaryDirectory(prefix='laser_tracker_bench_rates_') as tmp, \
            ProcessPoolExecutor(max(1, args.jobs)) as pool:
        other = [(f'{name}@{suffix}', name, Path(tmp) / f'{name}@{suffix}', scanner)
                 for suffix, scanner in other_scanners(args) for name in HOKUYO_SCENARIOS]
        for (row, *_), bag in zip(other, pool.map(_simulate, other)):
            jobs += [(row, mode, args.config, bag) for mode in modes]
        done = pool.map(_job, jobs) if args.jobs > 1 else map(_job, jobs)
        for name, mode, row in done:
            results.setdefault(name, {})[mode] = row
            if not args.markdown:
                print(f'{name:<32} {mode:<9} ' + ', '.join(f'{k} {v}' for k, v in row.items()),
                      flush=True)
    if args.markdown:
        print(markdown_table(results, modes))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2) + '\n')
    return 0


def markdown_table(results: dict, modes) -> str:
    lines = ['| recording | mode | paths found | people detected | false detections | MOTA '
             '| false-positive frames | ID switches | median error (m) |',
             '|---|---|---|---|---|---|---|---|---|']
    for name, rows in results.items():
        for mode in modes:
            r = rows.get(mode)
            if r is None:
                continue
            paths = f'{r["paths"]} of {r["paths_taken"]}' if r['paths_taken'] else '-'
            people = f'{r["detected"]} of {r["passing"]}' if r['passing'] else '-'
            lines.append(f'| `{name}` | {mode} | {paths} | {people} | {r["false_detections"]} | '
                         f'{_num(r["mota"])} | {r["false_positives"]} | {r["switches"]} | '
                         f'{_num(r["median_error"])} |')
    return '\n'.join(lines)


def _num(v: float) -> str:
    return '-' if v != v else f'{v:.3f}'          # NaN: nothing to score
