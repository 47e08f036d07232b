"""``laser-tracker bench pipeline``: speed and memory of the whole pipeline.

Scans and odometry of bundled recordings (361-beam SICK scans and the 768-beam Hokuyo
recording) are loaded into memory first; then the pipeline (ego-motion included) runs over
them, the recording repeated with continuing stamps until ``--scans`` scans have been
processed, single-threaded. Printed: scans per second, the same at reference speed,
milliseconds per stage (ego-motion, grid, difference, blobs, tracking), and peak traced
memory (tracemalloc) for a short run and a long one (``--long-scans``, default a simulated
hour at 5 Hz = 18,000 scans) with checkpoints, to show it stays flat. Without bundled
recordings the scans come from the simulator (``laser_tracker.tools.sim``), else from a
synthetic room with a walker.

Start-up (``--start-up N``): per recording, ``N`` fresh Python processes, each loading the
compiled kernels from the cache: the seconds to import the package and to make the
pipeline (kernels loaded, stages warmed up), the milliseconds of each of the first scans
(the odometry before each included) and the median scan further on (scans 21 to
``--start-up-scans``); then the same first scans through a second pipeline of the same
process, whose code has run them once (what the first scans would take with nothing left
to warm up). Medians over the processes. ``--cold`` adds one process with an empty cache,
which compiles every kernel first.

Reference speed makes figures of different machines comparable: ``t`` is the best of 3
timings of 1,000 rounds of ``cKDTree(a).query(b); np.linalg.svd(a.T @ b)`` on two 361 x 2
random arrays, per round; a machine with ``t`` = :data:`REFERENCE_ROUND` (0.174 ms) is the
reference, and a figure of ``n`` scans per second measured here is ``n * t / 0.174 ms`` there.
The compiled kernels are loaded (or compiled) before anything is timed.
"""
from __future__ import annotations

import argparse
import gc
import json
import logging
import os
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

from laser_tracker.core.pipeline import STAGES, Pipeline, PipelineConfig
from laser_tracker.core.scan import Scan
from laser_tracker.errors import LaserTrackerError

DEFAULT_BAGS = ('exp1_stationary_single_walker', 'exp2_translating_static',
                'exp3_rotating_static', 'crossing_walkers', 'hokuyo_corridor_lobby')
#: Seconds per round of :func:`reference_round` on the reference machine.
REFERENCE_ROUND = 0.174e-3


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--bag', action='append', metavar='BAG',
                        help='recording(s) to use (path or bundled name; default: '
                        + ', '.join(DEFAULT_BAGS) + ')')
    parser.add_argument('--config', metavar='YAML', help='pipeline configuration')
    parser.add_argument('--scans', type=int, default=3000,
                        help='scans timed per recording (default 3000)')
    parser.add_argument('--short-scans', type=int, default=500,
                        help='scans of the short memory run (default 500)')
    parser.add_argument('--long-scans', type=int, default=18000,
                        help='scans of the long memory run (default 18000 = 1 h at 5 Hz; '
                        '0 = skip)')
    parser.add_argument('--start-up', type=int, default=0, metavar='N',
                        help='also time the start of N fresh processes per recording '
                        '(kernels from the cache): pipeline made, first scans, median scan '
                        'further on (default 0 = skip)')
    parser.add_argument('--start-up-scans', type=int, default=300, metavar='S',
                        help='scans per start-up process (default 300)')
    parser.add_argument('--cold', action='store_true',
                        help='with --start-up: one more process per recording with an empty '
                        'kernel cache (compiles every kernel: about a minute)')


class Events:
    """A recording in memory: receive-ordered ('odom', stamp, pose) / ('scan', Scan)."""

    def __init__(self, name: str, events: list, duration: float):
        self.name, self.events, self.duration = name, events, duration
        self.n_scans = sum(1 for e in events if e[0] == 'scan')

    def cycle(self, n_scans: int):
        """The events repeated with stamps shifted by the recording's length each time and
        the odometry continued from where the previous repeat ended."""
        from laser_tracker.core.geometry import compose, inverse

        odo = [e[2] for e in self.events if e[0] == 'odom']
        step = compose(odo[-1], inverse(odo[0])) if odo else None
        done, k = 0, 0
        offset = np.zeros(3)
        while done < n_scans:
            shift = k * self.duration
            for e in self.events:
                if e[0] == 'odom':
                    yield ('odom', e[1] + shift, tuple(compose(offset, e[2])))
                else:
                    s = e[1]
                    yield ('scan', Scan(stamp=s.stamp + shift, ranges=s.ranges,
                                        angle_min=s.angle_min,
                                        angle_increment=s.angle_increment,
                                        range_min=s.range_min, range_max=s.range_max,
                                        frame_id=s.frame_id))
                    done += 1
                    if done >= n_scans:
                        return
            k += 1
            if step is not None:
                offset = compose(step, offset)


def load_bag(name: str) -> Events:
    from laser_tracker.conversions import odometry_from_msg, scan_from_msg
    from laser_tracker.tools.bag import iter_messages, topics
    from laser_tracker.tools.bag import resolve_bag

    path = resolve_bag(name)
    info = topics(path)
    wanted = [t for t in ('/scan', '/odom') if t in info]
    events = []
    for topic, _, msg in iter_messages(path, wanted):
        if topic == '/scan':
            events.append(('scan', scan_from_msg(msg)))
        else:
            o = odometry_from_msg(msg)
            events.append(('odom', o.stamp, (o.x, o.y, o.theta)))
    return _finish(Path(path).name, events)


def _finish(name: str, events: list) -> Events:
    stamps = [e[1].stamp for e in events if e[0] == 'scan']
    period = float(np.median(np.diff(stamps))) if len(stamps) > 1 else 0.2
    duration = (stamps[-1] - stamps[0]) + period if stamps else 1.0
    odo = [e[1] for e in events if e[0] == 'odom']
    if odo:
        duration = max(duration, odo[-1] - min(odo[0], stamps[0]) + period)
    return Events(name, events, duration)


def load_sim(name: str) -> Events:
    from laser_tracker.tools.sim import scenarios
    from laser_tracker.tools.sim.recorder import record

    rec = record(scenarios.build(name))
    events = [(t, 1, ('scan', s)) for s, t in zip(rec.scans, rec.scan_receive_times)]
    o = rec.odometry
    recv = getattr(o, 'receive_times', o.stamps)
    events += [(t, 0, ('odom', float(s), tuple(p))) for s, t, p in zip(o.stamps, recv, o.poses)]
    events.sort(key=lambda e: (e[0], e[1]))
    return _finish(f'{name} (simulated)', [e[2] for e in events])


def synthetic(n: int = 200) -> Events:
    """A 10 m x 8 m room seen by a stationary 361-beam scanner, a 'leg' crossing it."""
    angles = np.radians(np.linspace(-90, 90, 361))
    c, s = np.cos(angles), np.sin(angles)
    events = []
    for k in range(n):
        t = 0.2 * k
        with np.errstate(divide='ignore'):
            r = np.minimum(np.where(c > 1e-9, 6.0 / c, np.inf),
                           np.where(np.abs(s) > 1e-9, 4.0 / np.abs(s), np.inf))
        px, py = 3.0, -3.0 + (0.8 * t) % 6.0
        b = px * c + py * s
        disc = b * b - (px * px + py * py - 0.06 ** 2)
        hit = (disc > 0) & (b > 0)
        r = np.where(hit, np.minimum(r, b - np.sqrt(np.maximum(disc, 0))), r)
        r = np.minimum(r, 7.99) + np.random.default_rng(k).normal(0, 0.01, r.size)
        events.append(('odom', t, (0.0, 0.0, 0.0)))
        events.append(('scan', Scan(stamp=t, ranges=r, angle_min=angles[0],
                                    angle_increment=angles[1] - angles[0], range_min=0.0,
                                    range_max=8.0)))
    return _finish('synthetic room', events)


def sources(names, named: bool = True) -> list[Events]:
    """The recordings ``names``: a bag, else the simulator scenario of that name. A ``named``
    one (given by the user) that is neither is an error; the defaults fall back to synthetic
    scans when none can be had (an install without its recordings)."""
    out = []
    for name in names:
        try:
            out.append(load_bag(name))
            continue
        except Exception as exc:  # noqa: BLE001 - fall back to the simulator
            problem = exc
        try:
            out.append(load_sim(Path(name).name))
            continue
        except Exception:  # noqa: BLE001 - fall back to synthetic scans
            pass
        if named:
            raise LaserTrackerError(f'bench pipeline: {name!r} is neither a readable recording '
                                    f'nor a simulator scenario ({problem})')
    return out or [synthetic()]


def timed_run(events: Events, config: PipelineConfig, n_scans: int, repeat: int = 3) -> dict:
    """Whole passes over the recording (a fresh pipeline each, as a restarted node would
    see it) until ``n_scans`` scans; the fastest of ``repeat`` such runs is kept."""
    warm = Pipeline(config)
    for e in events.events[:60]:                       # ray tables, imports, caches
        warm.add_odometry(e[1], e[2]) if e[0] == 'odom' else warm.step(e[1])
    best = None
    for _ in range(repeat):
        done, wall, cpu = 0, 0.0, 0.0
        times = {s: 0.0 for s in STAGES}
        sources: dict = {}
        created = 0
        while done < n_scans:
            pipeline = Pipeline(config, profile=True)
            gc.collect()
            t0, c0 = time.perf_counter(), time.process_time()
            for e in events.events:
                if e[0] == 'odom':
                    pipeline.add_odometry(e[1], e[2])
                else:
                    pipeline.step(e[1])
                    done += 1
                    if done >= n_scans:
                        break
            wall += time.perf_counter() - t0
            cpu += time.process_time() - c0
            for k, v in pipeline.times.items():
                times[k] += v
            for k, v in pipeline.sources.items():
                sources[k] = sources.get(k, 0) + v
            created += pipeline.tracker.stats['created']
        if best is None or wall < best['wall']:
            best = {'scans': done, 'wall': wall, 'cpu': cpu,
                    'stages': {k: 1e3 * v / done for k, v in times.items()},
                    'sources': sources, 'created': created}
    return best


def memory_run(events: Events, config: PipelineConfig, n_scans: int,
               checkpoints: int = 6) -> list[tuple[int, float, float]]:
    """(scans done, current MB, peak MB) at checkpoints, tracemalloc running throughout."""
    marks = sorted({max(1, round(n_scans * (i + 1) / checkpoints)) for i in range(checkpoints)})
    pipeline = Pipeline(config)
    gc.collect()
    tracemalloc.start()
    out, done = [], 0
    try:
        for e in events.cycle(n_scans):
            if e[0] == 'odom':
                pipeline.add_odometry(e[1], e[2])
                continue
            pipeline.step(e[1])
            done += 1
            if marks and done == marks[0]:
                marks.pop(0)
                cur, peak = tracemalloc.get_traced_memory()
                out.append((done, cur / 1e6, peak / 1e6))
    finally:
        tracemalloc.stop()
    return out


#: First scans timed one by one at start-up.
FIRST_SCANS = 6


def scan_times(pipeline: Pipeline, events: Events, n_scans: int) -> list[float]:
    """Seconds of each of the first ``n_scans`` scans of ``events`` in ``pipeline``: its
    :meth:`Pipeline.step` and the :meth:`Pipeline.add_odometry` of the odometry received
    since the previous scan (the events are made one by one as a node receives them,
    outside the timing)."""
    out: list[float] = []
    spent = 0.0
    for e in events.cycle(n_scans):
        t0 = time.perf_counter()
        if e[0] == 'odom':
            pipeline.add_odometry(e[1], e[2])
            spent += time.perf_counter() - t0
            continue
        pipeline.step(e[1])
        out.append(spent + time.perf_counter() - t0)
        spent = 0.0
    return out


def start_up_trial(started: float, name: str, config_path: str | None, n_scans: int) -> dict:
    """One fresh process's start (``started``: ``time.perf_counter()`` before the package
    was imported); prints and returns its figures (see the module docstring)."""
    imported = time.perf_counter() - started
    logging.basicConfig(level=logging.ERROR)
    logging.getLogger('laser_tracker').setLevel(logging.ERROR)
    config = PipelineConfig.load(config_path) if config_path else PipelineConfig()
    events = sources([name])[0]
    t0 = time.perf_counter()
    pipeline = Pipeline(config)
    made = time.perf_counter() - t0
    first = scan_times(pipeline, events, max(n_scans, FIRST_SCANS))
    again = scan_times(Pipeline(config), events, FIRST_SCANS)
    out = {'import': imported, 'made': made, 'scans': first[:FIRST_SCANS],
           'median': float(np.median(first[20:] or first)), 'again': again,
           'beams': next(e[1].n_beams for e in events.events if e[0] == 'scan')}
    print(json.dumps(out))
    return out


def start_up(name: str, config_path: str | None, n_scans: int, cold: bool = False) -> dict:
    """:func:`start_up_trial` in a fresh Python process (``cold``: with an empty, temporary
    kernel cache)."""
    import laser_tracker

    env = dict(os.environ)
    root = str(Path(laser_tracker.__file__).resolve().parent.parent)
    env['PYTHONPATH'] = os.pathsep.join(p for p in (root, env.get('PYTHONPATH')) if p)
    code = ('import time; t = time.perf_counter(); '
            'from laser_tracker.tools.bench_pipeline import start_up_trial; '
            f'start_up_trial(t, {name!r}, {config_path!r}, {int(n_scans)})')
    with tempfile.TemporaryDirectory() as cache:
        if cold:
            env['NUMBA_CACHE_DIR'] = cache
        done = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True,
                              text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def _start_up_rows(name: str, trials: list[dict], label: str) -> list[str]:
    def med(key):
        return float(np.median([t[key] for t in trials]))

    def ms(values):
        return ' '.join(f'{1e3 * v:>6.2f}' for v in np.median(values, axis=0))

    beams = trials[0]['beams']
    return [f'{name[:34]:<34} {beams:>5} {label:>9} {med("import"):>8.2f} {med("made"):>8.2f} '
            f'{ms([t["scans"] for t in trials])} {1e3 * med("median"):>7.2f}',
            f'{"":<34} {"":>5} {"":>9} {"":>8} {"same":>8} '
            f'{ms([t["again"] for t in trials])}']


def reference_round(rounds: int = 1000, repeat: int = 3) -> float:
    """Seconds per round of ``cKDTree(a).query(b); np.linalg.svd(a.T @ b)`` on two 361 x 2
    random arrays (best of ``repeat`` timings of ``rounds`` rounds)."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(0)
    a, b = rng.random((361, 2)), rng.random((361, 2))
    best = float('inf')
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(rounds):
            cKDTree(a).query(b)
            np.linalg.svd(a.T @ b)
        best = min(best, (time.perf_counter() - t0) / rounds)
    return best


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.ERROR)
    logging.getLogger('laser_tracker').setLevel(logging.ERROR)   # the figures, not the logs
    config = PipelineConfig.load(args.config) if args.config else PipelineConfig()
    recordings = sources(args.bag or DEFAULT_BAGS, named=bool(args.bag))
    print(f'pipeline benchmark: {", ".join(r.name for r in recordings)}; one core, '
          f'grid {config.grid.cells} x {config.grid.cells} cells of '
          f'{config.grid.resolution * 100:.0f} cm, Kalman mode {config.kalman.mode}')
    Pipeline(config)                      # compiled kernels: loaded (or compiled) now
    t = reference_round()
    scale = t / REFERENCE_ROUND
    print(f'reference round here t = {1e3 * t:.3f} ms (reference machine '
          f'{1e3 * REFERENCE_ROUND:.3f} ms): at reference speed = scans/s x {scale:.3f}')
    header = f'{"recording":<34} {"beams":>5} {"scans/s":>8} {"at ref":>7} ' + \
        ' '.join(f'{s:>10}' for s in STAGES) + f' {"total ms":>9}'
    print('\nspeed (ms per scan by stage; ego-motion source counts below)')
    print(header)
    for rec in recordings:
        beams = next(e[1].n_beams for e in rec.events if e[0] == 'scan')
        r = timed_run(rec, config, args.scans)
        per = r['scans'] / r['wall']
        stages = ' '.join(f'{r["stages"][s]:>10.3f}' for s in STAGES)
        print(f'{rec.name[:34]:<34} {beams:>5} {per:>8.0f} {per * scale:>7.0f} {stages} '
              f'{1e3 * r["wall"] / r["scans"]:>9.3f}')
        print(f'{"":<34} {"":>5} {"":>8} {"":>7} ego-motion stage '
              f'{1e3 * r["stages"]["ego_motion"]:.0f} us per scan; sources {r["sources"]}, '
              f'cpu/wall {r["cpu"] / r["wall"]:.2f}, hypotheses created {r["created"]}')
    if args.start_up > 0:
        print(f'\nstart-up: per recording {args.start_up} fresh processes, kernels loaded from '
              f'the cache (medians); seconds to import the package and to make the pipeline '
              f'(kernels loaded, stages warmed up), ms of scans 1-{FIRST_SCANS} (odometry '
              f'included) and the median scan of scans 21-{args.start_up_scans}; "same": '
              f'those first scans again through a second pipeline of the process')
        print(f'{"recording":<34} {"beams":>5} {"processes":>9} {"import s":>8} {"made s":>8} '
              + ' '.join(f'{"scan " + str(k + 1):>6}' for k in range(FIRST_SCANS))
              + f' {"median":>7}')
        for name in args.bag or DEFAULT_BAGS:
            trials = [start_up(name, args.config, args.start_up_scans)
                      for _ in range(args.start_up)]
            for line in _start_up_rows(name, trials, str(len(trials))):
                print(line)
            if args.cold:
                cold = start_up(name, args.config, args.start_up_scans, cold=True)
                print(_start_up_rows(name, [cold], 'cold')[0])
    rec = recordings[0]   # the first (stationary) recording cycles cleanly
    print(f'\nmemory (tracemalloc, pipeline state only) on {rec.name}, stamps continuing '
          f'over repeats')
    for label, n in (('short', args.short_scans), ('long', args.long_scans)):
        if n <= 0:
            continue
        t0 = time.perf_counter()
        marks = memory_run(rec, config, n)
        wall = time.perf_counter() - t0
        hours = n / 5.0 / 3600.0
        print(f'  {label} run: {n} scans ({hours:.2f} h at 5 Hz), {wall:.1f} s with tracing')
        for done, cur, peak in marks:
            print(f'    after {done:>6} scans: current {cur:6.2f} MB, peak {peak:6.2f} MB')
    try:
        import resource
        rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
        print(f'  process max RSS {rss:.0f} MB (includes the recordings loaded in memory)')
    except (ImportError, OSError):  # pragma: no cover - not on every platform
        pass
    return 0
