"""``laser-tracker demo BAG``: replay a recording, show tracks as they appear, then score them.

BAG is a path, or the name of a bundled recording (``exp1_stationary_single_walker``) looked
up in ``bags/`` of the source tree or ``share/laser_tracker/bags`` of an installed package.
The replay runs with a progress bar and prints each track when it is first confirmed; at the
end the evaluation against ground truth (``laser-tracker evaluate``) is printed if the
recording has ground truth, otherwise the replay summary and the unlabelled report.
"""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

from laser_tracker.errors import LaserTrackerError
from laser_tracker.tools.atomic import check_output, removed_on_failure, write_json
from laser_tracker.tools.bag import has_ground_truth, resolve_bag

log = logging.getLogger(__name__)

def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('bag', metavar='BAG', help='a recording, or a bundled recording name')
    parser.add_argument('--out', metavar='DIR',
                        help='output folder (default out/<recording name>)')
    parser.add_argument('--config', metavar='YAML', help='tracker configuration (ROS parameter '
                        'file; default: the package defaults)')
    parser.add_argument('--threshold', type=float, default=0.75,
                        help='evaluation match distance in metres (default 0.75)')


def _printer():
    """on_confirmed callback: one line per newly confirmed track, kept clear of the bar."""
    try:
        from tqdm import tqdm
        write = tqdm.write
    except ImportError:  # pragma: no cover - tqdm is a dependency
        write = print

    def on_confirmed(stamp, track_id, x, y, vx, vy):
        write(f'  t={stamp:9.3f} s  track {track_id:>5}  confirmed at ({x:7.2f}, {y:7.2f}) m  '
              f'velocity ({vx:5.2f}, {vy:5.2f}) m/s')
    return on_confirmed


def _summary_lines(summary: dict) -> list[str]:
    skipped = summary.get('scans_skipped') or {}
    timing = summary.get('timing') or {}
    lines = [f'  scans replayed      {summary.get("scans", "?")} '
             f'({sum(skipped.values()) if isinstance(skipped, dict) else "?"} skipped)',
             f'  hypotheses created  {summary.get("hypotheses_created", "?")}',
             f'  confirmed tracks    {summary.get("confirmed_tracks", "?")}']
    if 'scans_per_s' in timing:
        lines.append(f'  speed               {timing["scans_per_s"]:.0f} scans/s')
    return lines


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.WARNING, format='%(levelname)s %(name)s: %(message)s')
    from laser_tracker.config import from_dict
    from laser_tracker.tools import evaluate as ev
    from laser_tracker.tools.scoring import EvaluationConfig

    bag = resolve_bag(args.bag)
    out = check_output(args.out or Path('out') / bag.name.removesuffix('.bag'), overwrite=True)
    eval_config = from_dict(EvaluationConfig, {'threshold': args.threshold})  # before replay
    try:
        from laser_tracker.tools.replay import replay_bag
    except ImportError as exc:
        raise LaserTrackerError(f'replay is not available: {exc}') from None
    labelled = has_ground_truth(bag)

    print(f'replaying {bag} -> {out}')
    print('tracks as they are confirmed (odometry frame):', flush=True)
    with removed_on_failure(out):
        summary = replay_bag(bag, config=args.config, out_dir=out, progress=True,
                             on_confirmed=_printer())
    print()
    print('replay summary:')
    print('\n'.join(_summary_lines(summary)))
    print()
    if labelled:
        result = ev.evaluate_replay(out, bag, eval_config)
    else:
        print(f'{bag} has no ground truth: the unlabelled report instead of the evaluation')
        result = ev.report_unlabelled(out, eval_config)
    figures = ev.write_figures(result, out)
    result.result['figures'] = [str(p) for p in figures]
    json_path = write_json(out / 'evaluation.json', result.result)
    print(ev.format_table(result.result))
    print()
    print('figures:')
    for p in sorted(set(out.glob('*.png')) | set(figures)):
        print(f'  {p}')
    print(f'evaluation: {json_path}')
    return 0
