"""``laser-tracker bench egomotion [LOG ...]``: ego-motion accuracy and time per scan, ours
beside kiss-icp, on CARMEN logs with corrected poses; plus a trajectory figure on a raw log.

Protocol (issue 3), per corrected log (default: intel-corrected and aces-corrected):

* reference = relative motion between consecutive corrected FLASER poses;
* odometry given to both matchers = that motion plus Gaussian noise (sigma 5 cm, 5 cm,
  2 deg per step, ``--seed``), chained into an odometry track (one sample per scan);
* error per step = the estimated relative motion minus the reference (translation norm,
  absolute rotation); median and 95th percentile over all steps;
* scans are stamped 1 s apart (the corrected logs are subsampled and their stamps go back in
  places; the odometry is synthetic, so only the order matters);
* ours runs with its defaults except the odometry noise model, set to the noise added
  (``odom_sigma_xy`` 0.05 m, ``odom_sigma_theta`` 2 deg per step, no distance terms);
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
import math
import time
from pathlib import Path

import numpy as np

from laser_tracker.core.egomotion import EgoMotionConfig, EgoMotionEstimator
from laser_tracker.core.geometry import between, compose
from laser_tracker.core.scan import Scan
from laser_tracker.tools.carmen import read_carmen
from laser_tracker.tools.data import real_data

DATA = real_data() / 'carmen'
DEFAULT_LOGS = ('intel-corrected.log.gz', 'aces-corrected.log.gz')
RAW_LOG = 'mit-csail.clf'
NOISE = (0.05, 0.05, math.radians(2.0))
STEP_DT = 1.0

#: ours: defaults, with the odometry noise model set to the noise this benchmark adds
BENCH_CONFIG = EgoMotionConfig(odom_sigma_xy=NOISE[0], odom_sigma_xy_per_m=0.0,
                               odom_sigma_theta=NOISE[2], odom_sigma_theta_per_rad=0.0)

KISS_SETTINGS = dict(voxel_size=0.1, max_range=12.0, max_points_per_voxel=20,
                     initial_threshold=0.5, min_motion_th=0.01)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('logs', nargs='*', help='CARMEN logs with corrected poses (default: '
                        'intel-corrected and aces-corrected in ../shared/data/carmen)')
    parser.add_argument('--seed', type=int, default=0, help='odometry noise seed (default 0)')
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
                        help=f'raw log for the figure (default ../shared/data/carmen/{RAW_LOG})')


# ------------------------------------------------------------------------ protocol


def noisy_odometry(reference: np.ndarray, start, seed: int) -> np.ndarray:
    """Odometry poses (N, 3): ``start`` then the reference increments plus noise, chained."""
    rng = np.random.default_rng(seed)
    noisy = reference + rng.normal(0.0, 1.0, reference.shape) * np.array(NOISE)
    poses = [np.asarray(start, dtype=float)]
    for inc in noisy:
        poses.append(compose(poses[-1], inc))
    return np.array(poses)


def step_errors(est: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-step translation error (m) and absolute rotation error (rad)."""
    d = np.array([between(r, e) for r, e in zip(ref, est)])
    return np.hypot(d[:, 0], d[:, 1]), np.abs(d[:, 2])


def summary(trans, rot, times) -> dict:
    ok = np.isfinite(trans)
    t, r = trans[ok], rot[ok]
    return {'trans_med': float(np.median(t)) if t.size else math.nan,
            'trans_p95': float(np.percentile(t, 95)) if t.size else math.nan,
            'rot_med': float(np.degrees(np.median(r))) if r.size else math.nan,
            'rot_p95': float(np.degrees(np.percentile(r, 95))) if r.size else math.nan,
            'time_med': float(np.median(times)) * 1e3 if len(times) else math.nan,
            'time_p95': float(np.percentile(times, 95)) * 1e3 if len(times) else math.nan,
            'failed': int(np.count_nonzero(~ok))}


def run_ours(scans: list[Scan], odom: np.ndarray, config: EgoMotionConfig | None = None):
    """Estimated relative motions (N-1, 3), per-update times, the estimates."""
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
    return motions, np.array(times[1:]), out, est.stats


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
    motions = np.array([between(poses[i - 1], poses[i]) for i in range(1, len(poses))])
    return motions, np.array(times[1:])


def load_corrected(path: Path):
    log = read_carmen(path)
    ranges = log.scan_ranges()
    scans = [Scan(stamp=STEP_DT * (i + 1), ranges=ranges[i], angle_min=log.angle_min,
                  angle_increment=log.angle_increment, range_min=0.0,
                  range_max=log.range_max) for i in range(len(log))]
    poses = log.laser_poses
    reference = np.array([between(poses[i - 1], poses[i]) for i in range(1, len(poses))])
    return scans, poses, reference


def bench_log(path: Path, seed: int, with_kiss: bool) -> dict:
    scans, poses, reference = load_corrected(path)
    odom = noisy_odometry(reference, poses[0], seed)
    motions, times, _, stats = run_ours(scans, odom, BENCH_CONFIG)
    trans, rot = step_errors(motions, reference)
    result = {'log': path.name, 'scans': len(scans), 'beams': scans[0].n_beams,
              'ours': summary(trans, rot, times), 'sources': dict(stats)}
    odo_trans, odo_rot = step_errors(np.array([between(odom[i - 1], odom[i])
                                               for i in range(1, len(odom))]), reference)
    result['odometry'] = summary(odo_trans, odo_rot, [])
    if with_kiss:
        k_motions, k_times = run_kiss(scans, odom)
        kt, kr = step_errors(k_motions, reference)
        result['kiss'] = summary(kt, kr, k_times)
    return result


def oracle_floor(path: Path, n_map: int, start_sigma=(0.005, 0.005, math.radians(0.2)),
                 seed: int = 5) -> dict:
    """Errors of converged ICP against ``n_map`` scans at the reference poses (see --oracle)."""
    from laser_tracker.core import icp

    scans, poses, reference = load_corrected(path)
    est = EgoMotionEstimator(BENCH_CONFIG)
    pts = [est._points(s) for s in scans]
    normals = [icp.scan_normals(p, BENCH_CONFIG.normal_max_gap) for p in pts]
    rng = np.random.default_rng(seed)
    motions = []
    for k in range(1, len(scans)):
        local = icp.LocalMap(n_map)
        for j in range(max(0, k - n_map), k):
            nrm, ok = normals[j]
            local.add(poses[j], pts[j][ok], nrm[ok])
        start = compose(poses[k], rng.normal(0.0, 1.0, 3) * np.array(start_sigma))
        res = icp.align(pts[k], local, start, (0.1,), BENCH_CONFIG.kernel_ratio,
                        steps_per_association=3, final_associations=10)
        motions.append(between(poses[k - 1], res.pose))
    trans, rot = step_errors(np.array(motions), reference)
    return summary(trans, rot, [])


# ------------------------------------------------------------------------- output


def _row(name, s) -> str:
    return (f'  {name:<10} {100 * s["trans_med"]:7.3f} {100 * s["trans_p95"]:7.3f}   '
            f'{s["rot_med"]:7.3f} {s["rot_p95"]:7.3f}   {s["time_med"]:7.3f} '
            f'{s["time_p95"]:7.3f}')


def print_result(r: dict) -> None:
    print(f'{r["log"]}: {r["scans"]} scans, {r["beams"]} beams, '
          f'{r["scans"] - 1} steps')
    print('  matcher    trans cm med/p95   rot deg med/p95   ms/scan med/p95')
    print(_row('ours', r['ours']))
    if 'kiss' in r:
        print(_row('kiss-icp', r['kiss']))
        o, k = r['ours'], r['kiss']
        ratios = [o[key] / k[key] if k[key] else math.nan for key in
                  ('trans_med', 'trans_p95', 'rot_med', 'rot_p95', 'time_med', 'time_p95')]
        print('  ours/kiss  ' + '   '.join(f'{a:6.2f} {b:6.2f} ' for a, b in
                                           zip(ratios[::2], ratios[1::2])))
    o = r['odometry']
    print(f'  (odometry given: {100 * o["trans_med"]:.2f} / {100 * o["trans_p95"]:.2f} cm, '
          f'{o["rot_med"]:.3f} / {o["rot_p95"]:.3f} deg)')
    if r['ours']['failed']:
        print(f'  ours gave no pose for {r["ours"]["failed"]} steps')
    src = {k: v for k, v in r['sources'].items() if not k.startswith('note')}
    print('  sources: ' + ', '.join(f'{k} {v}' for k, v in sorted(src.items())))


def targets_met(r: dict) -> str:
    o = r['ours']
    checks = [100 * o['trans_med'] <= 2.0, 100 * o['trans_p95'] <= 6.0,
              o['rot_med'] <= 0.25, o['rot_p95'] <= 1.0]
    names = ['trans med <= 2 cm', 'trans p95 <= 6 cm', 'rot med <= 0.25 deg',
             'rot p95 <= 1 deg']
    if 'kiss' in r:
        k = r['kiss']
        for key, name in (('trans_med', 'trans med'), ('trans_p95', 'trans p95'),
                          ('rot_med', 'rot med'), ('rot_p95', 'rot p95')):
            checks.append(o[key] < k[key])
            names.append(f'{name} < kiss')
    return ', '.join(f'{n}: {"yes" if c else "NO"}' for n, c in zip(names, checks))


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
    logging.getLogger('laser_tracker.core.egomotion').setLevel(logging.ERROR)
    logs = [Path(p) for p in args.logs] or [DATA / name for name in DEFAULT_LOGS]
    with_kiss = not args.no_kiss and kiss_available()
    if not args.no_kiss and not with_kiss:
        print('kiss-icp is not installed: only our figures are printed')
    status = 0
    if args.oracle is not None:
        for path in logs:
            if not path.exists():
                print(f'{path}: not found (real data lives in ../shared/data beside the repo)')
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
            print(f'{path}: not found (real data lives in ../shared/data beside the repo)')
            status = 1
            continue
        r = bench_log(path, args.seed, with_kiss)
        print_result(r)
        print('  targets: ' + targets_met(r))
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
