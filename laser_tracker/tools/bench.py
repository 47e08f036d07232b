"""``laser-tracker bench SUBJECT``: benchmarks that print figures (never pass/fail tests).

Subjects live in their own modules with ``add_arguments(parser)`` and ``run(args)``.
"""
from __future__ import annotations

import argparse
import importlib

SUBJECTS: dict[str, tuple[str, str]] = {
    'egomotion': ('laser_tracker.tools.bench_egomotion',
                  'ICP accuracy and time per scan on CARMEN logs, beside kiss-icp'),
    'pipeline': ('laser_tracker.tools.bench_pipeline',
                 'scans per second, ms per stage and peak memory of the whole pipeline'),
    'detector': ('laser_tracker.tools.bench_detector',
                 'person detector (legs): ms per scan, recall on person_following'),
    'sick': ('laser_tracker.tools.bench_sick',
             'SICK driver reliability under injected faults'),
    'graph': ('laser_tracker.tools.bench_graph',
              'latency and drops of the node graph over DDS at 75 Hz'),
    'real': ('laser_tracker.tools.bench_real',
             'the tracker on the public real recordings, scored'),
    'sims': ('laser_tracker.tools.bench_sims',
             'the tracker on the bundled simulated recordings, scored'),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest='subject', metavar='SUBJECT', required=True)
    for name, (module_name, help_text) in SUBJECTS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        try:
            module = importlib.import_module(module_name)
        except ImportError:
            p.set_defaults(_bench=None, _missing=module_name)
            continue
        module.add_arguments(p)
        p.set_defaults(_bench=module)
    sub.add_parser('all', help='every benchmark with its defaults').set_defaults(_bench='all')


def run(args: argparse.Namespace) -> int:
    if args._bench == 'all':
        status = 0
        for name, (module_name, _) in SUBJECTS.items():
            print(f'== bench {name} ==', flush=True)
            module = importlib.import_module(module_name)
            p = argparse.ArgumentParser()
            module.add_arguments(p)
            status |= int(module.run(p.parse_args([])) or 0)
        return status
    if args._bench is None:
        raise SystemExit(f'benchmark module {args._missing} is not available')
    return int(args._bench.run(args) or 0)
