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
import sys
from pathlib import Path

from laser_tracker.errors import InputFileError, LaserTrackerError
from laser_tracker.tools.atomic import write_json

log = logging.getLogger(__name__)

PACKAGE = 'laser_tracker'


def bag_folders() -> list[Path]:
    """Where bundled recordings may live, most specific first."""
    folders = [Path(__file__).resolve().parents[2] / 'bags']  # source tree / editable install
    try:
        from ament_index_python.packages import get_package_share_directory
        folders.append(Path(get_package_share_directory(PACKAGE)) / 'bags')
    except Exception:  # ament_index_python absent, or the package not in an ament index
        pass
    folders.append(Path(sys.prefix) / 'share' / PACKAGE / 'bags')  # pip install
    unique = []
    for f in folders:
        if f not in unique:
            unique.append(f)
    return unique


def bundled_bags() -> list[str]:
    names = set()
    for folder in bag_folders():
        if folder.is_dir():
            names.update(p.name for p in folder.iterdir() if p.is_dir() or p.suffix == '.bag')
    return sorted(names)


def resolve_bag(name: str | Path) -> Path:
    """A recording path as given if it exists, else a bundled recording of that name."""
    path = Path(name)
    if path.exists():
        return path
    for folder in bag_folders():
        candidate = folder / path.name
        if candidate.exists():
            return candidate
    known = bundled_bags()
    hint = f'bundled: {", ".join(known)}' if known else \
        'no bundled recordings found (generate them with `make bags`)'
    raise InputFileError(name, f'no such recording; {hint}')


def has_ground_truth(bag: Path) -> bool:
    from laser_tracker.tools.bag import GROUND_TRUTH_TOPIC, PLATFORM_TRUTH_TOPIC, topics

    found = topics(bag)
    return GROUND_TRUTH_TOPIC in found and PLATFORM_TRUTH_TOPIC in found


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
    out = Path(args.out) if args.out else Path('out') / bag.name.removesuffix('.bag')
    eval_config = from_dict(EvaluationConfig, {'threshold': args.threshold})  # before replay
    try:
        from laser_tracker.tools.replay import replay_bag
    except ImportError as exc:
        raise LaserTrackerError(f'replay is not available: {exc}') from None
    labelled = has_ground_truth(bag)

    print(f'replaying {bag} -> {out}')
    print('tracks as they are confirmed (odometry frame):', flush=True)
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
