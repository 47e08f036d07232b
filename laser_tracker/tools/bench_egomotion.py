"""``laser-tracker bench egomotion [LOG ...]``: ego-motion accuracy and time per scan, ours
beside kiss-icp, on CARMEN logs with corrected poses; plus a trajectory figure on a raw log.

Protocol, per corrected log (default: intel-corrected, aces-corrected and
freiburg-079-part1-corrected) and per odometry noise model (default: ``poor`` and
``realistic``, :mod:`laser_tracker.tools.odometry_noise`):

* reference = relative motion between consecutive corrected FLASER poses;
* odometry given to both matchers = those motions with the model's noise (``--seed``),
  chained into an odometry track (one sample per scan);
* error per step = the estimated relative motion minus the reference (translation norm,
  absolute rotation); median and 95th percentile over all steps;
* drift = the same error of the relative pose over every window of ``DRIFT_WINDOW`` (10)
  consecutive scans (the relative pose error of the chained estimate); mean and 95th
  percentile over all windows;
* stamps: the log's own when they increase and the log is at its native rate (median step
  under 1 s: freiburg, ~4 Hz); else 1 s apart (intel and aces are subsampled and their stamps
  go back in places; the odometry is synthetic, so only the order matters);
* ours runs with its defaults (``--prior noise`` instead: the odometry noise model set to the
  noise added and not adapted, the first protocol of intel and aces);
* time = ``time.perf_counter()`` around ``EgoMotionEstimator.update()`` only (odometry
  interpolation, ICP, checks and the local-map update included) and around
  ``KissICP.register_frame()`` for kiss-icp.

kiss-icp (optional dependency) gets the same scans as 3D points (z = 0) and the same odometry
increment as its initial guess (``last_delta`` is set to the increment before each
``register_frame``, so its constant-velocity prediction becomes the odometry prediction). Its
configuration was tuned for these 2D logs by a grid search (max_range 10..50 m, voxel
0.05..0.2 m, fixed or adaptive thresholds): voxel 0.1 m, max_range 12 m, deskew off, adaptive
threshold (initial 0.5 m, min motion 0.01 m), 20 points per voxel, one thread.

The figure (``--figure``, default ``out/egomotion_mit_csail.png``) uses the raw mit-csail log
(odometry in its FLASER lines, no reference): the odometry-only trajectory with the scans drawn
from it, beside the ICP-corrected trajectory with the scans drawn from it. Its time per
361-beam scan is printed too.

``--oracle N`` (diagnostic, no timing): for every scan, point-to-line ICP (fine association
0.1 m, 10 re-associations, so it converges) against the previous N scans placed at their
*reference* poses, started within a few millimetres of the reference pose (N(0, 5 mm, 5 mm,
0.2 deg), seed 5). Its error against the reference is how far the matching optimum is from
the reference when the map is perfect and the start is right: a floor for any matcher of
this kind that does not see the reference.
"""
from __future__ import annotations

import argparse
import dataclasses
import functools
import math
import time
from pathlib import Path

import numpy as np

from laser_tracker.core.egomotion import EgoMotionConfig, EgoMotionEstimator
from laser_tracker.core.geometry import between, compose
from laser_tracker.core.scan import Scan
from laser_tracker.tools import odometry_noise
from laser_tracker.tools.carmen import read_carmen
from laser_tracker.tools.data import real_data

DATA = real_data() / 'carmen'
DEFAULT_LOGS = ('intel-corrected.log.gz', 'aces-corrected.log.gz',
                'freiburg-079-part1-corrected.log.gz')
DEFAULT_NOISE = ('poor', 'realistic')
RAW_LOG = 'mit-csail.clf'
STEP_DT = 1.0
DRIFT_WINDOW = 10

KISS_SETTINGS = dict(voxel_size=0.1, max_range=12.0, max_points_per_voxel=20,
                     initial_threshold=0.5, min_motion_th=0.01)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('logs', nargs='*', help='CARMEN logs with corrected poses (default: '
                        'intel-corrected, aces-corrected and freiburg-079-part1-corrected in '
                        'the carmen folder of $LASER_TRACKER_DATA)')
    parser.add_argument('--noise', type=_noise_list, default=list(DEFAULT_NOISE),
                        help='odometry noise models, comma-separated, of '
                        f'{", ".join(odometry_noise.MODELS)} (default: '
                        f'{",".join(DEFAULT_NOISE)})')
    parser.add_argument('--seed', type=int, default=0, help='odometry noise seed (default 0)')
    parser.add_argument('--prior', choices=('defaults', 'noise'), default='defaults',
                        help='ours with its defaults, or with the odometry noise model set to '
                        'the noise added and not adapted (default %(default)s)')
    parser.add_argument('--no-kiss', action='store_true', help='skip kiss-icp')
    parser.add_argument('--figure', default='out/egomotion_mit_csail.png',
                        help='trajectory figure on the raw mit-csail log (default %(default)s)')
    parser.add_argument('--no-figure', action='store_true', help='skip the mit-csail figure')
    parser.add_argument('--figure-only', action='store_true',
                        help='only the mit-csail run and figure')
    parser.add_argument('--oracle', type=int, nargs='*', metavar='N', default=None,
                        help='diagnostic: converged ICP against the previous N scans at the '
                        'reference poses, started near the reference (default N: 5 20 100); '
                        'prints the floor it reaches, then exits')
    parser.add_argument('--raw-log', default=None,
                        help=f'raw log for the figure (default {DATA / RAW_LOG})')


def _noise_list(text: str) -> list[str]:
    models = [m.strip() for m in text.split(',') if m.strip()]
    bad = [m for m in models if m not in odometry_noise.MODELS]
    if bad or not models:
        raise argparse.ArgumentTypeError(
            f'unknown noise model(s) {", ".join(bad) or "(none given)"}: choose from '
            f'{", ".join(odometry_noise.MODELS)}')
    return models


def _log_path(name: str) -> Path:
    """A log argument: a path, or the name of a log in the shared data folder."""
    path = Path(name)
    return path if path.exists() or path.parent != Path('.') else DATA / name


# ------------------------------------------------------------------------ protocol


def noise_prior_config(model: str) -> EgoMotionConfig:
    """Ours with the odometry noise model set to the noise ``model`` adds, not adapted."""
    if model == 'poor':
        sxy, sth = odometry_noise.POOR_SIGMA[0], odometry_noise.POOR_SIGMA[2]
        fields = dict(odom_sigma_xy=sxy, odom_sigma_xy_per_m=0.0, odom_sigma_theta=sth,
                      odom_sigma_theta_per_rad=0.0)
    elif model == 'realistic':
        fields = dict(odom_sigma_xy=1e-3, odom_sigma_xy_per_m=odometry_noise.REALISTIC_XY_PER_M
                      + odometry_noise.REALISTIC_BIAS[0],
                      odom_sigma_theta=1e-4, odom_sigma_theta_per_rad=0.01)
    else:
        fields = dict(odom_sigma_xy=1e-4, odom_sigma_xy_per_m=0.0, odom_sigma_theta=1e-5,
                      odom_sigma_theta_per_rad=0.0)
    names = {f.name for f in dataclasses.fields(EgoMotionConfig)}
    if 'odom_adaptive' in names:
        fields['odom_adaptive'] = False
    return EgoMotionConfig(**fields)


def step_errors(est: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-step translation error (m) and absolute rotation error (rad)."""
    d = np.array([between(r, e) for r, e in zip(ref, est)])
    return np.hypot(d[:, 0], d[:, 1]), np.abs(d[:, 2])


def window_errors(est_poses: np.ndarray, ref_poses: np.ndarray,
                  window: int = DRIFT_WINDOW) -> tuple[np.ndarray, np.ndarray]:
    """Translation (m) and rotation (rad) error of the relative pose over every window of
    ``window`` steps (NaN where an estimated pose is missing)."""
    n = len(ref_poses) - window
    if n <= 0:
        return np.zeros(0), np.zeros(0)
    est = np.array([between(est_poses[i], est_poses[i + window]) for i in range(n)])
    ref = np.array([between(ref_poses[i], ref_poses[i + window]) for i in range(n)])
    return step_errors(est, ref)


def summary(trans, rot, times, drift=None) -> dict:
    ok = np.isfinite(trans)
    t, r = trans[ok], rot[ok]
    out = {'trans_med': float(np.median(t)) if t.size else math.nan,
           'trans_p95': float(np.percentile(t, 95)) if t.size else math.nan,
           'rot_med': float(np.degrees(np.median(r))) if r.size else math.nan,
           'rot_p95': float(np.degrees(np.percentile(r, 95))) if r.size else math.nan,
           'time_med': float(np.median(times)) * 1e3 if len(times) else math.nan,
           'time_p95': float(np.percentile(times, 95)) * 1e3 if len(times) else math.nan,
           'failed': int(np.count_nonzero(~ok))}
    if drift is not None:
        dt, dr = drift
        ok = np.isfinite(dt)
        dt, dr = dt[ok], dr[ok]
        out.update(drift_trans=float(np.mean(dt)) if dt.size else math.nan,
                   drift_trans_p95=float(np.percentile(dt, 95)) if dt.size else math.nan,
                   drift_rot=float(np.degrees(np.mean(dr))) if dr.size else math.nan,
                   drift_rot_p95=(float(np.degrees(np.percentile(dr, 95))) if dr.size
                                  else math.nan))
    return out


def run_ours(scans: list[Scan], odom: np.ndarray, config: EgoMotionConfig | None = None):
    """Estimated poses (N, 3), relative motions (N-1, 3), per-update times, estimates, stats."""
    est = EgoMotionEstimator(config)
    out, times = [], []
    for scan, pose in zip(scans, odom):
        est.add_odometry(scan.stamp, pose)
        t0 = time.perf_counter()
        e = est.update(scan)
        times.append(time.perf_counter() - t0)
        out.append(e)
    poses = np.array([e.pose for e in out])
    motions = np.array([between(poses[i - 1], poses[i]) if np.isfinite(poses[i - 1]).all()
                        and np.isfinite(poses[i]).all() else np.full(3, np.nan)
                        for i in range(1, len(out))])
    return poses, motions, np.array(times[1:]), out, est.stats


def _se2_matrix(p) -> np.ndarray:
    m = np.eye(4)
    c, s = math.cos(p[2]), math.sin(p[2])
    m[:2, :2] = [[c, -s], [s, c]]
    m[0, 3], m[1, 3] = p[0], p[1]
    return m


def kiss_available() -> bool:
    try:
        import kiss_icp.kiss_icp  # noqa: F401
    except ImportError:
        return False
    return True


def run_kiss(scans: list[Scan], odom: np.ndarray):
    """kiss-icp's poses (N, 3), relative motions (N-1, 3) and per-frame times."""
    from kiss_icp.config import KISSConfig
    from kiss_icp.config.config import (AdaptiveThresholdConfig, DataConfig, MappingConfig,
                                        RegistrationConfig)
    from kiss_icp.kiss_icp import KissICP

    k = KISS_SETTINGS
    cfg = KISSConfig(
        data=DataConfig(max_range=k['max_range'], min_range=0.0, deskew=False),
        mapping=MappingConfig(voxel_size=k['voxel_size'],
                              max_points_per_voxel=k['max_points_per_voxel']),
        registration=RegistrationConfig(max_num_iterations=500, convergence_criterion=1e-4,
                                        max_num_threads=1),
        adaptive_threshold=AdaptiveThresholdConfig(initial_threshold=k['initial_threshold'],
                                                   min_motion_th=k['min_motion_th']))
    kiss = KissICP(cfg)
    poses, times = [], []
    for i, scan in enumerate(scans):
        xy = scan.points()
        pts = np.column_stack((xy, np.zeros(len(xy))))
        if i > 0:
            kiss.last_delta = _se2_matrix(between(odom[i - 1], odom[i]))
        t0 = time.perf_counter()
        kiss.register_frame(pts, np.zeros(len(pts)))
        times.append(time.perf_counter() - t0)
        m = kiss.last_pose
        poses.append((m[0, 3], m[1, 3], math.atan2(m[1, 0], m[0, 0])))
    poses = np.array(poses)
    motions = np.array([between(poses[i - 1], poses[i]) for i in range(1, len(poses))])
    return poses, motions, np.array(times[1:])


@functools.lru_cache(maxsize=2)
def load_corrected(path: Path):
    """Scans, reference poses (N, 3), reference motions (N-1, 3) and how they are stamped
    (cached: each noise model reads the log once; nothing here is modified)."""
    log = read_carmen(path)
    ranges = log.scan_ranges()
    dt = np.diff(log.stamps)
    native = bool(dt.size and np.all(dt > 0) and np.median(dt) < 1.0)
    stamps = log.stamps if native else STEP_DT * (np.arange(len(log)) + 1.0)
    scans = [Scan(stamp=float(stamps[i]), ranges=ranges[i], angle_min=log.angle_min,
                  angle_increment=log.angle_increment, range_min=0.0,
                  range_max=log.range_max) for i in range(len(log))]
    poses = log.laser_poses
    reference = odometry_noise.increments_of(poses)
    return scans, poses, reference, ('log stamps' if native else f'{STEP_DT:g} s apart')


def bench_log(path: Path, seed: int, with_kiss: bool, noise: str = 'poor',
              config: EgoMotionConfig | None = None) -> dict:
    scans, poses, reference, stamping = load_corrected(path)
    odom = odometry_noise.noisy_odometry(poses, noise, seed)
    est_poses, motions, times, _, stats = run_ours(scans, odom, config)
    trans, rot = step_errors(motions, reference)
    result = {'log': path.name, 'noise': noise, 'stamps': stamping, 'scans': len(scans),
              'beams': scans[0].n_beams,
              'ours': summary(trans, rot, times, window_errors(est_poses, poses)),
              'sources': dict(stats)}
    odo_trans, odo_rot = step_errors(odometry_noise.increments_of(odom), reference)
    result['odometry'] = summary(odo_trans, odo_rot, [], window_errors(odom, poses))
    if with_kiss:
        k_poses, k_motions, k_times = run_kiss(scans, odom)
        kt, kr = step_errors(k_motions, reference)
        result['kiss'] = summary(kt, kr, k_times, window_errors(k_poses, poses))
    return result


def oracle_floor(path: Path, n_map: int, start_sigma=(0.005, 0.005, math.radians(0.2)),
                 seed: int = 5) -> dict:
    """Errors of converged ICP against ``n_map`` scans at the reference poses (see --oracle)."""
    from laser_tracker.core import icp

    scans, poses, reference, _ = load_corrected(path)
    config = EgoMotionConfig()
    matcher = EgoMotionEstimator(config).matcher
    pts = [matcher.match(s)[0] for s in scans]
    rng = np.random.default_rng(seed)
    motions = []
    for k in range(1, len(scans)):
        local = icp.LocalMap(n_map, config.normal_max_gap)
        for j in range(max(0, k - n_map), k):
            local.add_scan(poses[j], pts[j])
        start = compose(poses[k], rng.normal(0.0, 1.0, 3) * np.array(start_sigma))
        res = icp.align(pts[k], local, start, (0.1,), config.kernel_ratio,
                        steps_per_association=3, final_associations=10)
        motions.append(between(poses[k - 1], res.pose))
    trans, rot = step_errors(np.array(motions), reference)
    return summary(trans, rot, [])


# ------------------------------------------------------------------------- output


ACCURACY_KEYS = ('trans_med', 'trans_p95', 'rot_med', 'rot_p95', 'drift_trans', 'drift_rot')


def _row(name, s) -> str:
    return (f'  {name:<10} {100 * s["trans_med"]:7.3f} {100 * s["trans_p95"]:7.3f}   '
            f'{s["rot_med"]:7.3f} {s["rot_p95"]:7.3f}   {100 * s["drift_trans"]:7.3f} '
            f'{s["drift_rot"]:7.3f}' + (f'   {s["time_med"]:7.3f} {s["time_p95"]:7.3f}'
                                          if math.isfinite(s['time_med']) else ''))


def print_result(r: dict) -> None:
    print(f'{r["log"]} ({r["noise"]} odometry): {r["scans"]} scans, {r["beams"]} beams, '
          f'{r["scans"] - 1} steps, stamps: {r["stamps"]}')
    print(f'  matcher    trans cm med/p95   rot deg med/p95   drift{DRIFT_WINDOW} cm/deg  '
          f'ms/scan med/p95')
    print(_row('ours', r['ours']))
    if 'kiss' in r:
        print(_row('kiss-icp', r['kiss']))
        o, k = r['ours'], r['kiss']
        ratios = [o[key] / k[key] if k[key] else math.nan for key in
                  ACCURACY_KEYS + ('time_med', 'time_p95')]
        print('  ours/kiss  ' + '   '.join(f'{a:6.2f} {b:6.2f} ' for a, b in
                                           zip(ratios[::2], ratios[1::2])))
    print(_row('odometry', r['odometry']))
    if r['ours']['failed']:
        print(f'  ours gave no pose for {r["ours"]["failed"]} steps')
    src = {k: v for k, v in r['sources'].items() if not k.startswith('note')}
    print('  sources: ' + ', '.join(f'{k} {v}' for k, v in sorted(src.items())))


def beats_kiss(r: dict) -> str:
    """Which accuracy figures of ours are below kiss-icp's ('' without kiss-icp)."""
    if 'kiss' not in r:
        return ''
    o, k = r['ours'], r['kiss']
    names = ('trans med', 'trans p95', 'rot med', 'rot p95', 'drift trans', 'drift rot')
    return ', '.join(f'{n}: {"yes" if o[key] < k[key] else "NO"}'
                     for n, key in zip(names, ACCURACY_KEYS))


# ------------------------------------------------------------------------- figure


def raw_log_run(path: Path):
    log = read_carmen(path)
    scans = list(log.scans())
    est = EgoMotionEstimator()
    out, times = [], []
    for scan, stamp, pose in zip(scans, log.stamps, log.odom_poses):
        est.add_odometry(stamp, pose)
        t0 = time.perf_counter()
        out.append(est.update(scan))
        times.append(time.perf_counter() - t0)
    return log, scans, out, np.array(times[1:]), est.stats


def save_figure(path: Path, log, scans, estimates) -> None:
    from laser_tracker.tools.figures import pyplot
    plt = pyplot()

    from laser_tracker.core.geometry import transform_points

    odo = log.odom_poses
    icp_poses = np.array([e.pose for e in estimates])
    fig, axes = plt.subplots(1, 2, figsize=(16, 8.5), sharex=True, sharey=True)
    step = max(1, len(scans) // 400)
    for ax, poses, title in ((axes[0], odo, 'odometry only'),
                             (axes[1], icp_poses, 'odometry + ICP (ours)')):
        pts = []
        for i in range(0, len(scans), step):
            if np.isfinite(poses[i]).all():
                p = scans[i].points(max_range=30.0)
                pts.append(transform_points(poses[i], p[::2]))
        if pts:
            allp = np.concatenate(pts)
            ax.plot(allp[:, 0], allp[:, 1], ',', color='0.35', alpha=0.5)
        ax.plot(poses[:, 0], poses[:, 1], '-', color='tab:red', lw=1.2, label='trajectory')
        ax.set_title(f'{Path(log.path).name}: {title}')
        ax.set_aspect('equal')
        ax.set_xlabel('x (m)')
        ax.legend(loc='upper right')
    axes[0].set_ylabel('y (m)')
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ---------------------------------------------------------------------------- run


def run(args: argparse.Namespace) -> int:
    import logging

    from laser_tracker.tools.atomic import check_output
    logging.getLogger('laser_tracker.core.egomotion').setLevel(logging.ERROR)
    if not args.no_figure and args.oracle is None:
        check_output(args.figure, overwrite=True)       # before minutes of benchmark
    logs = [_log_path(p) for p in args.logs] or [DATA / name for name in DEFAULT_LOGS]
    with_kiss = not args.no_kiss and kiss_available()
    if not args.no_kiss and not with_kiss:
        print('kiss-icp is not installed: only our figures are printed')
    status = 0
    if args.oracle is not None:
        for path in logs:
            if not path.exists():
                print(f'{path}: not found (the public recordings: $LASER_TRACKER_DATA, see README.md)')
                status = 1
                continue
            for n_map in args.oracle or (5, 20, 100):
                o = oracle_floor(path, n_map)
                print(f'{path.name}: oracle map of {n_map:3d} reference-placed scans: '
                      f'{100 * o["trans_med"]:.3f} / {100 * o["trans_p95"]:.3f} cm, '
                      f'{o["rot_med"]:.3f} / {o["rot_p95"]:.3f} deg (median / p95)')
        return status
    for path in ([] if args.figure_only else logs):
        if not path.exists():
            print(f'{path}: not found (the public recordings: $LASER_TRACKER_DATA, see README.md)')
            status = 1
            continue
        for noise in args.noise:
            config = noise_prior_config(noise) if args.prior == 'noise' else None
            r = bench_log(path, args.seed, with_kiss, noise, config)
            print_result(r)
            if with_kiss:
                print('  below kiss-icp: ' + beats_kiss(r))
    if not args.no_figure:
        raw = Path(args.raw_log) if args.raw_log else DATA / RAW_LOG
        if not raw.exists():
            print(f'{raw}: not found, no figure')
            return status or 1
        log, scans, estimates, times, stats = raw_log_run(raw)
        save_figure(Path(args.figure), log, scans, estimates)
        src = {k: v for k, v in stats.items() if not k.startswith('note')}
        print(f'{raw.name}: {len(scans)} scans, {log.n_beams} beams (raw odometry): '
              f'{1e3 * np.median(times):.3f} ms/scan median, '
              f'{1e3 * np.percentile(times, 95):.3f} ms 95th; sources: '
              + ', '.join(f'{k} {v}' for k, v in sorted(src.items())))
        print(f'figure: {args.figure}')
    return status
