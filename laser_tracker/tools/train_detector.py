"""``laser-tracker train-detector``: train the leg classifier of the person detector.

Input: recordings (ROS 1 or rosbag2) of two kinds.

* Positive recordings: a LaserScan topic and, before each scan to learn from, a
  ``geometry_msgs/PoseArray`` (``--labels-topic``, default ``/leg_cluster_positions``) with
  the positions of the leg clusters in that scan (scanner frame, metres): the layout of the
  leg_tracker project's ``positive_*_extracted.bag``. A labels message applies to the next
  scan only. Instead of labels, ``--box XMIN XMAX YMIN YMAX`` declares every cluster whose
  centre lies in that box of the scanner frame a leg (record someone walking inside a free
  area that nothing else enters). A cluster within ``--match-radius`` of a label is a leg;
  the other clusters of a positive scan are not used (someone else may be in view).
* Negative recordings: scans with nobody in view; every cluster of every LaserScan topic is
  a negative (each topic is a separate group for the held-out evaluation).

A cluster is a leg when a label lies within ``--match-radius`` (0.1 m) of its centroid: the
leg_tracker labels are the centroids of that project's own clusters (0.13 m Euclidean
clustering), which our 0.13 m jump-distance clusters reproduce within 2 cm for 98 % of the
labels; 0.1 m also takes a leg whose cluster is cut differently, while staying below the
distance between two legs. The classifier: ``--trees`` (50) gradient-boosted trees of depth
``--depth`` (3) (scikit-learn's GradientBoostingClassifier, subsample 0.8, legs weighted to
the total weight of the negatives), written for numpy inference (a few kilobytes).

Without recordings on the command line the leg_tracker training data of the public data
folder is used (``laser_tracker.tools.data.real_data()``), which is how the packaged model
was made: ``laser-tracker train-detector --augment-range 2,3 --output
laser_tracker/models/person_detector.npz``.

Augmentation (``--augment-range``, e.g. 2,3): copies of the training scans as if every cluster
stood 2 and 3 times farther away, so that legs beyond the training recordings' 5 m are found
(the scans' range noise is not scaled). The shipped model is trained with ``--augment-range
2,3``: fewer false tracks on the real recordings, more people found far away in the
simulated ones, a little recall lost on near legs (README.md, "The person detector").

Evaluation before the final fit: the groups (one per positive recording, one per negative
topic; with fewer recordings of a kind than folds, blocks of consecutive scans of each) are
split into ``--folds`` consecutive blocks; each block is predicted by a model
trained on the others, on the scans as recorded and resampled to 0.5 and 1 degree between
beams (SICK LMS resolutions), and as if every cluster stood 3 times farther; only clusters
within ``--max-range`` (8 m) count. Printed per
fold: recall of the labelled legs, precision among the held-out clusters, false legs per
negative scan. The leg threshold written to the model (unless ``--threshold``) is the one
at which the pooled held-out negative scans (at the recorded resolution) give
``--false-legs`` (0.75) false legs per scan: a rate a user can read, and one that holds on
clutter the model has not seen. The best F1 (``--false-legs 0``) depends on how many legs
the recordings happen to hold against how much clutter, and moves with the training set.
The final model is fitted on everything.
"""
from __future__ import annotations

import argparse
import glob
import logging
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from laser_tracker.core.person_detector import LegClassifier, save_model
from laser_tracker.core.scan import Scan, ScanError
from laser_tracker.core.segmentation import FEATURE_NAMES, FEATURE_SET, SegmentConfig, segment
from laser_tracker.errors import InputFileError, LaserTrackerError

log = logging.getLogger(__name__)

DEFAULT_POSITIVE = 'leg_tracker/training/positive_*_extracted.bag'
DEFAULT_NEGATIVE = 'leg_tracker/training/negative_2.bag'
LABELS_TOPIC = '/leg_cluster_positions'
SCAN_TYPE = 'sensor_msgs/msg/LaserScan'
POSES_TYPE = 'geometry_msgs/msg/PoseArray'
RESAMPLED = (('0.5 deg', np.radians(0.5)), ('1 deg', np.radians(1.0)))
#: False legs per scan with nobody in view at the recorded threshold (``--false-legs``).
FALSE_LEGS = 0.75
#: Range (m) within which the false legs of --false-legs are counted: the room around the
#: training recordings' people (within 5 m of the robot), not the clutter far beyond them
#: that the detector also classifies at run time (``person_detector.max_range``).
CALIBRATION_RANGE = 8.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--positive', action='append', metavar='BAG',
                        help='recording with scans and leg labels (repeat; default: the '
                        'leg_tracker positive_*_extracted.bag of the public data folder)')
    parser.add_argument('--negative', action='append', metavar='BAG',
                        help='recording with nobody in view (repeat; default: the '
                        'leg_tracker negative_2.bag)')
    parser.add_argument('--scan-topic', metavar='TOPIC',
                        help='scan topic of the positive recordings (default: their only '
                        'LaserScan topic)')
    parser.add_argument('--labels-topic', default=LABELS_TOPIC, metavar='TOPIC',
                        help=f'PoseArray topic of leg positions (default {LABELS_TOPIC})')
    parser.add_argument('--box', nargs=4, type=float, metavar=('XMIN', 'XMAX', 'YMIN', 'YMAX'),
                        help='instead of labels: clusters centred in this box of the scanner '
                        'frame (m) are legs')
    parser.add_argument('--match-radius', type=float, default=0.1,
                        help='a cluster whose centre lies within this distance (m) of a '
                        'label is a leg (default 0.1)')
    seg = SegmentConfig()
    parser.add_argument('--jump-distance', type=float, default=seg.jump_distance,
                        help='cluster jump distance, m (default segments.jump_distance, '
                        f'{seg.jump_distance})')
    parser.add_argument('--min-points', type=int, default=seg.min_points,
                        help=f'fewest points of a cluster (default {seg.min_points})')
    parser.add_argument('--max-width', type=float, default=seg.max_width,
                        help=f'widest cluster classified, m (default {seg.max_width})')
    parser.add_argument('--augment-noise', default='', metavar='SIGMAS',
                        help='comma-separated range noise levels (m): each adds a copy of '
                        'the training scans with Gaussian noise of that standard deviation '
                        '(a noisier scanner than the recording\'s)')
    parser.add_argument('--augment-resolution', default='', metavar='DEGREES',
                        help='comma-separated beam spacings (degrees): each adds a copy of '
                        'the training scans resampled to it (a sparser scanner)')
    parser.add_argument('--augment-range', default='', metavar='FACTORS',
                        help='comma-separated factors k: each adds a copy of the training '
                        'scans as if every cluster stood k times farther: beams k times '
                        'sparser, the range feature k times larger (e.g. 2,3: the '
                        'training legs stand within 5 m, people are found beyond)')
    parser.add_argument('--trees', type=int, default=50, help='boosting rounds (default 50)')
    parser.add_argument('--depth', type=int, default=3, help='tree depth (default 3)')
    parser.add_argument('--learning-rate', type=float, default=0.2,
                        help='boosting learning rate (default 0.2)')
    parser.add_argument('--folds', type=int, default=3,
                        help='held-out blocks of recordings for the evaluation (default 3; '
                        '0 or 1 = no evaluation); with fewer recordings of a kind, blocks of '
                        'consecutive scans')
    parser.add_argument('--false-legs', type=float, default=FALSE_LEGS, metavar='RATE',
                        help='the leg threshold recorded is the one at which the held-out '
                        'scans with nobody in view give RATE false legs per scan (clusters '
                        f'within --max-range; default {FALSE_LEGS}); 0 = the threshold of '
                        'the best held-out F1')
    parser.add_argument('--max-range', type=float, default=CALIBRATION_RANGE,
                        help='only the clusters within this range (m) are counted by '
                        '--false-legs and in the held-out figures (default '
                        f'{CALIBRATION_RANGE}: where the training recordings\' people are)')
    parser.add_argument('--threshold', type=float,
                        help='leg threshold to record (default: by --false-legs)')
    parser.add_argument('--seed', type=int, default=0, help='random seed (default 0)')
    parser.add_argument('--output', '-o', required=True, metavar='NPZ',
                        help='model file to write')
    parser.add_argument('--json', metavar='PATH', help='also write the report as JSON')


# ------------------------------------------------------------------------------- data


@dataclass
class LabelledScan:
    """A scan, its leg labels ((L, 2) scanner frame; None = nobody in view) and its group."""

    scan: Scan
    legs: np.ndarray | None
    group: str
    box: tuple | None = None


def _scan_topics(path: Path) -> list[str]:
    from laser_tracker.tools.bag import topics

    return sorted(t for t, (kind, _) in topics(path).items() if kind == SCAN_TYPE)


def read_positive(path: str | Path, scan_topic: str | None = None,
                  labels_topic: str = LABELS_TOPIC, box=None) -> list[LabelledScan]:
    """Labelled scans of a positive recording (see the module help)."""
    from laser_tracker.conversions import scan_from_msg
    from laser_tracker.tools.bag import iter_messages, scan_topic_of, topics

    path = Path(path)
    info = topics(path)
    scan_topic = scan_topic_of(path, scan_topic)
    wanted = [scan_topic]
    if box is None:
        if info.get(labels_topic, ('',))[0] != POSES_TYPE:
            raise InputFileError(path, f'no {POSES_TYPE} topic {labels_topic} with leg labels '
                                 '(give --labels-topic, or --box)')
        wanted.append(labels_topic)
    out, pending, skipped, unlabelled = [], None, 0, 0
    for topic, _, msg in iter_messages(path, wanted):
        if topic == labels_topic and box is None:
            pending = np.array([(p.position.x, p.position.y) for p in msg.poses],
                               dtype=float).reshape(-1, 2)
            continue
        try:
            scan = scan_from_msg(msg)
        except ScanError:
            skipped += 1
            continue
        if box is not None:
            out.append(LabelledScan(scan, np.zeros((0, 2)), path.name, tuple(box)))
        elif pending is None or not np.isfinite(pending).all():
            unlabelled += 1
        else:
            out.append(LabelledScan(scan, pending, path.name))
        pending = None
    if skipped or unlabelled:
        log.warning('%s: %d malformed scans skipped, %d scans without labels skipped', path,
                    skipped, unlabelled)
    if not out:
        raise InputFileError(path, f'no labelled scans on {scan_topic}')
    return out


def read_negative(path: str | Path) -> list[LabelledScan]:
    """Every scan of every LaserScan topic of a recording with nobody in view."""
    from laser_tracker.conversions import scan_from_msg
    from laser_tracker.tools.bag import iter_messages

    path = Path(path)
    topics = _scan_topics(path)
    if not topics:
        raise InputFileError(path, 'no LaserScan topic')
    out, skipped = [], 0
    for topic, _, msg in iter_messages(path, topics):
        try:
            out.append(LabelledScan(scan_from_msg(msg), None, f'neg:{path.name}{topic}'))
        except ScanError:
            skipped += 1
    if skipped:
        log.warning('%s: %d malformed scans skipped', path, skipped)
    return out


def resample(scan: Scan, increment: float) -> Scan:
    """The scan as a scanner with ``increment`` rad between beams over the same field of view
    would see it: for each new beam the recorded beam nearest in angle."""
    inc = abs(float(increment)) * (1.0 if scan.angle_increment > 0 else -1.0)
    span = (scan.n_beams - 1) * scan.angle_increment
    n = int(np.floor(span / inc + 1e-9)) + 1
    angles = scan.angle_min + inc * np.arange(n)
    index = np.clip(np.rint((angles - scan.angle_min) / scan.angle_increment).astype(int), 0,
                    scan.n_beams - 1)
    return Scan(stamp=scan.stamp, ranges=scan.ranges[index], angle_min=scan.angle_min,
                angle_increment=inc, range_min=scan.range_min, range_max=scan.range_max,
                frame_id=scan.frame_id)


@dataclass
class ClusterTable:
    """Features and labels of every cluster: ``y`` 1 leg, 0 negative, -1 not used;
    ``leg`` the index of the labelled leg a leg cluster matches (-1 for the others)."""

    X: np.ndarray
    y: np.ndarray
    group: np.ndarray
    leg: np.ndarray
    negative_scans: dict         # group -> number of negative scans
    labelled_legs: dict          # group -> number of labelled legs

    def select(self, groups) -> np.ndarray:
        return np.isin(self.group, list(groups)) & (self.y >= 0)

    def count(self, counts: dict, groups) -> int:
        return sum(n for g, n in counts.items() if g in groups)


def add_noise(scan: Scan, sigma: float, rng: np.random.Generator) -> Scan:
    """The scan with Gaussian noise of ``sigma`` metres on its valid ranges."""
    ranges = scan.ranges.copy()
    valid = scan.valid()
    ranges[valid] += rng.normal(0.0, sigma, int(valid.sum()))
    return Scan(stamp=scan.stamp, ranges=ranges, angle_min=scan.angle_min,
                angle_increment=scan.angle_increment, range_min=scan.range_min,
                range_max=scan.range_max, frame_id=scan.frame_id)


def cluster_table(items: list[LabelledScan], match_radius: float, jump_distance: float,
                  min_points: int, max_width: float, increment: float | None = None,
                  noise: float = 0.0, seed: int = 0, farther: float = 1.0) -> ClusterTable:
    """Features and labels of the clusters of ``items``, optionally of the scans resampled
    to ``increment`` rad between beams, with ``noise`` metres of range noise, or seen as if
    ``farther`` times farther away (at the range of a cluster, its points are then as far
    apart as ``farther`` times sparser beams put them; its shape in metres is the same)."""
    feats, labels, groups, legs = [], [], [], []
    negative_scans: dict[str, int] = {}
    labelled: dict[str, int] = {}
    rng = np.random.default_rng(seed)
    for item in items:
        step = increment if farther == 1.0 else abs(item.scan.angle_increment) * farther
        scan = item.scan if step is None else resample(item.scan, step)
        if noise > 0:
            scan = add_noise(scan, noise, rng)
        c = segment(scan, jump_distance, min_points, max_width)
        leg = np.full(c.count, -1, dtype=np.int64)
        first_leg = sum(labelled.values())      # global index of this scan's first label
        if item.legs is None:
            negative_scans[item.group] = negative_scans.get(item.group, 0) + 1
            y = np.zeros(c.count, dtype=np.int8)
        elif item.box is not None:
            x0, x1, y0, y1 = item.box
            inside = (c.xy[:, 0] >= x0) & (c.xy[:, 0] <= x1) & (c.xy[:, 1] >= y0) & \
                (c.xy[:, 1] <= y1)
            y = np.where(inside, 1, -1).astype(np.int8)
            leg[inside] = first_leg + np.arange(int(inside.sum()))
            labelled[item.group] = labelled.get(item.group, 0) + int(inside.sum())
        else:
            y = np.full(c.count, -1, dtype=np.int8)
            if c.count and item.legs.shape[0]:
                d = np.hypot(*(c.xy[:, None, :] - item.legs[None, :, :]).transpose(2, 0, 1))
                match = d.min(axis=1) <= match_radius
                y[match] = 1
                leg[match] = first_leg + d.argmin(axis=1)[match]
            labelled[item.group] = labelled.get(item.group, 0) + item.legs.shape[0]
        if farther != 1.0:
            c.features[:, FEATURE_NAMES.index('distance')] *= farther
        feats.append(c.features)
        labels.append(y)
        legs.append(leg)
        groups.append(np.full(c.count, item.group, dtype=object))
    X = np.concatenate(feats) if feats else np.zeros((0, len(FEATURE_NAMES)))
    return ClusterTable(X=X, y=np.concatenate(labels), group=np.concatenate(groups).astype(str),
                        leg=np.concatenate(legs), negative_scans=negative_scans,
                        labelled_legs=labelled)


# ---------------------------------------------------------------------------- training


def fit(X: np.ndarray, y: np.ndarray, trees: int, depth: int, learning_rate: float,
        seed: int):
    """A scikit-learn gradient-boosting classifier, classes weighted to equal total weight."""
    from sklearn.ensemble import GradientBoostingClassifier

    n_pos, n_neg = int((y == 1).sum()), int((y == 0).sum())
    if n_pos == 0 or n_neg == 0:
        raise LaserTrackerError(f'training needs legs and negatives: {n_pos} leg clusters, '
                                f'{n_neg} negative clusters')
    weight = np.where(y == 1, n_neg / n_pos, 1.0)
    model = GradientBoostingClassifier(n_estimators=trees, max_depth=depth,
                                       learning_rate=learning_rate, subsample=0.8,
                                       random_state=seed)
    model.fit(X, y, sample_weight=weight)
    return model


def export(model, meta: dict | None = None) -> LegClassifier:
    """The fitted GradientBoostingClassifier as complete trees for numpy inference."""
    estimators = [e[0] for e in model.estimators_]
    depth = max(1, max(e.tree_.max_depth for e in estimators))
    inner, leaves = 2 ** depth - 1, 2 ** depth
    feature = np.zeros((len(estimators), inner), dtype=np.intp)
    threshold = np.full((len(estimators), inner), np.inf)
    value = np.zeros((len(estimators), leaves))
    lr = float(model.learning_rate)
    for t, est in enumerate(estimators):
        tree = est.tree_
        stack = [(0, 0, 0)]            # (sklearn node, complete-tree position, level)
        while stack:
            node, pos, level = stack.pop()
            left, right = tree.children_left[node], tree.children_right[node]
            if level == depth:
                value[t, pos - inner] = lr * float(tree.value[node].ravel()[0])
                continue
            if left == -1:             # a leaf above the full depth: repeat it below
                stack.append((node, 2 * pos + 1, level + 1))
                stack.append((node, 2 * pos + 2, level + 1))
                continue
            feature[t, pos] = tree.feature[node]
            threshold[t, pos] = tree.threshold[node]
            stack.append((left, 2 * pos + 1, level + 1))
            stack.append((right, 2 * pos + 2, level + 1))
    probe = np.zeros((1, len(FEATURE_NAMES)))
    bias = float(model.decision_function(probe)[0]) - \
        sum(lr * float(e.predict(probe)[0]) for e in estimators)
    return LegClassifier(feature, threshold, value, bias, meta)


# --------------------------------------------------------------------------- evaluation


def split_recordings(items: list[LabelledScan], folds: int) -> bool:
    """If the positive or the negative recordings are fewer than ``folds``, make each of
    them ``folds`` groups of consecutive scans (``name#i``), so that every held-out block
    has both kinds; returns whether it did."""
    changed = False
    for negative in (False, True):
        part = [i for i in items if (i.legs is None) == negative]
        names = sorted({i.group for i in part})
        if not part or len(names) >= folds:
            continue
        changed = True
        for name in names:
            scans = [i for i in part if i.group == name]
            for k, chunk in enumerate(np.array_split(np.arange(len(scans)), folds)):
                for j in chunk:
                    scans[j].group = f'{name}#{k}'
    return changed


def split_groups(groups: list[str], folds: int) -> list[set[str]]:
    """Consecutive blocks of the sorted positive groups and of the negative groups."""
    pos = sorted(g for g in groups if not g.startswith('neg:'))
    neg = sorted(g for g in groups if g.startswith('neg:'))
    blocks = [set() for _ in range(folds)]
    for part in (pos, neg):
        for i, chunk in enumerate(np.array_split(np.array(part, dtype=object), folds)):
            blocks[i].update(chunk.tolist())
    return [b for b in blocks if b]


def scores(p: np.ndarray, y: np.ndarray, leg: np.ndarray, threshold: float,
           labelled_legs: int, negative_scans: int) -> dict:
    """Recall: labelled legs with a cluster classified as a leg (a leg seen as no cluster,
    e.g. under ``min_points`` at a coarse resolution, is missed); precision: among the
    clusters classified as legs; false legs per scan of the negative recordings."""
    found = p >= threshold
    tp = int((found & (y == 1)).sum())
    fp = int((found & (y == 0)).sum())
    seen = np.unique(leg[found & (leg >= 0)]).size
    return {'labelled_legs': labelled_legs, 'leg_clusters': int((y == 1).sum()),
            'recall': seen / max(1, labelled_legs),
            'precision': tp / max(1, tp + fp),
            'false_legs_per_negative_scan': fp / max(1, negative_scans)}


def false_leg_threshold(p: np.ndarray, y: np.ndarray, negative_scans: int,
                        rate: float) -> float:
    """The lowest threshold at which at most ``rate`` false legs per negative scan reach it
    (k = rate x scans negatives): midway between the (k+1)-th most probable negative and
    the next more probable one, so that negatives of equal probability are all in or all
    out; 0.5 without negatives."""
    neg = np.sort(p[y == 0])[::-1]
    if neg.size == 0:
        return 0.5
    k = int(np.floor(rate * negative_scans + 1e-9))
    if k >= neg.size:
        return float(0.5 * neg[-1])
    first_out = neg[k]
    above = neg[neg > first_out]
    return float(0.5 * (first_out + (above.min() if above.size else 1.0)))


def best_f1_threshold(p: np.ndarray, y: np.ndarray) -> float:
    order = np.argsort(-p, kind='stable')
    ps, ys = p[order], y[order] == 1
    tp = np.cumsum(ys)
    fp = np.cumsum(~ys)
    f1 = 2 * tp / (tp + fp + ys.sum())
    last = np.r_[ps[1:] != ps[:-1], True]          # only between distinct scores
    i = int(np.argmax(np.where(last, f1, -1)))
    nxt = ps[i + 1] if i + 1 < ps.size else 0.0
    return float(0.5 * (ps[i] + nxt))


def run(args: argparse.Namespace) -> int:
    from laser_tracker.tools.atomic import atomic_path, check_output, write_json
    from laser_tracker.tools.data import real_recording

    for output in (args.output, args.json):       # before hours of training
        if output:
            check_output(output, overwrite=True)
    try:
        import sklearn  # noqa: F401
    except ImportError:
        raise LaserTrackerError('scikit-learn is needed to train: pip install '
                                "'laser_tracker[train]'") from None
    positive = args.positive or sorted(glob.glob(str(real_recording(DEFAULT_POSITIVE))))
    negative = args.negative or [str(real_recording(DEFAULT_NEGATIVE))]
    if not positive:
        raise LaserTrackerError(f'no positive recordings (none given, none at '
                                f'{real_recording(DEFAULT_POSITIVE)})')
    t0 = time.perf_counter()
    items: list[LabelledScan] = []
    for path in positive:
        items += read_positive(path, args.scan_topic, args.labels_topic, args.box)
    for path in negative:
        items += read_negative(path)
    seg = {'match_radius': args.match_radius, 'jump_distance': args.jump_distance,
           'min_points': args.min_points, 'max_width': args.max_width}
    if args.folds > 1 and split_recordings(items, args.folds):
        print(f'fewer recordings of a kind than --folds {args.folds}: each of them is split '
              'into consecutive blocks of scans for the held-out evaluation')
    table = cluster_table(items, **seg)
    augmented = _augmented_tables(items, seg, args)
    groups = sorted({i.group for i in items})
    print(f'{len(items)} scans: {(table.y == 1).sum()} leg clusters, {(table.y == 0).sum()} '
          f'negative clusters, {(table.y < 0).sum()} unlabelled (not used); '
          f'{len(groups)} groups ({time.perf_counter() - t0:.1f} s)', flush=True)
    fit_args = {'trees': args.trees, 'depth': args.depth,
                'learning_rate': args.learning_rate, 'seed': args.seed}
    report: dict = {'feature_set': FEATURE_SET, 'features': list(FEATURE_NAMES),
                    'segmentation': {k: seg[k] for k in ('jump_distance', 'min_points',
                                                         'max_width')},
                    'match_radius': args.match_radius, 'classifier': fit_args,
                    'augmentation': {'noise_m': _floats(args.augment_noise),
                                     'resolution_deg': _floats(args.augment_resolution),
                                     'range_factor': _floats(args.augment_range)},
                    'recordings': {'positive': [Path(p).name for p in positive],
                                   'negative': [Path(p).name for p in negative]},
                    'counts': {'scans': len(items), 'legs': int((table.y == 1).sum()),
                               'negatives': int((table.y == 0).sum())}}
    threshold = args.threshold
    if args.folds and args.folds > 1:
        threshold, report['held_out'] = _cross_validate(items, table, augmented, groups,
                                                        args.folds, seg, fit_args, threshold,
                                                        args.false_legs, args.max_range)
    elif threshold is None:
        threshold = 0.5
    model = fit(*training_rows([table] + augmented, set()), **fit_args)
    report['threshold'] = threshold
    if args.threshold is not None:
        rule = 'given'
    elif not (args.folds and args.folds > 1):
        rule = '0.5 (no held-out evaluation)'
    else:
        rule = f'{args.false_legs:g} false legs per negative scan' if args.false_legs > 0 \
            else 'best held-out F1'
    report['threshold_rule'] = rule
    meta = {'threshold': threshold, 'threshold_rule': rule, 'max_range': args.max_range,
            'segmentation': report['segmentation'],
            'trained_on': report['recordings'], 'counts': report['counts'],
            'classifier': fit_args, 'match_radius': args.match_radius,
            'augmentation': report['augmentation'],
            'held_out': report.get('held_out', {}).get('pooled')}
    classifier = export(model, meta)
    check = table.X[: min(2000, table.X.shape[0])]
    diff = np.abs(classifier.predict_proba(check) - model.predict_proba(check)[:, 1]).max()
    if diff > 1e-9:
        raise LaserTrackerError(f'exported trees disagree with scikit-learn by {diff:.2e}')
    with atomic_path(args.output, overwrite=True) as tmp:
        save_model(tmp, classifier)
    size = Path(args.output).stat().st_size
    report['model_file_bytes'] = size
    print(f'threshold {threshold:.3f}; wrote {args.output} ({size / 1024:.1f} KiB, '
          f'{classifier.n_trees} trees of depth {classifier.depth}) in '
          f'{time.perf_counter() - t0:.1f} s')
    if args.json:
        write_json(args.json, report)
    return 0


def _floats(text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(',') if v.strip()]
    except ValueError:
        raise LaserTrackerError(f'expected comma-separated numbers, got {text!r}') from None


def _augmented_tables(items, seg, args) -> list[ClusterTable]:
    out = []
    for k, sigma in enumerate(_floats(args.augment_noise)):
        out.append(cluster_table(items, noise=sigma, seed=args.seed + k, **seg))
    for deg in _floats(args.augment_resolution):
        out.append(cluster_table(items, increment=np.radians(deg), **seg))
    for k in _floats(args.augment_range):
        if k < 1:
            raise LaserTrackerError(f'--augment-range: factors are at least 1, got {k}')
        out.append(cluster_table(items, farther=k, **seg))
    return out


def training_rows(tables: list[ClusterTable], held_out: set[str]):
    """Labelled rows of ``tables`` outside the held-out groups."""
    xs, ys = [], []
    for t in tables:
        use = ~np.isin(t.group, list(held_out)) & (t.y >= 0)
        xs.append(t.X[use])
        ys.append(t.y[use])
    return np.concatenate(xs), np.concatenate(ys)


def _cross_validate(items, table, augmented, groups, folds, seg, fit_args, threshold,
                    false_legs=FALSE_LEGS, max_range=np.inf):
    blocks = split_groups(groups, folds)
    resampled = {name: cluster_table(items, increment=inc, **seg) for name, inc in RESAMPLED}
    tables = {'recorded': table, **resampled,
              '3x range': cluster_table(items, farther=3.0, **seg)}
    models = [fit(*training_rows([table] + augmented, block), **fit_args) for block in blocks]
    held = {name: [(t.select(b) & _within(t, max_range),
                    model.predict_proba(t.X[t.select(b) & _within(t, max_range)])[:, 1])
                   for b, model in zip(blocks, models)] for name, t in tables.items()}
    if threshold is None:
        p = np.concatenate([p for _, p in held['recorded']])
        y = np.concatenate([table.y[sel] for sel, _ in held['recorded']])
        if false_legs > 0:
            threshold = false_leg_threshold(p, y, sum(table.negative_scans.values()),
                                            false_legs)
            rule = f'{false_legs:g} false legs per scan with nobody in view'
        else:
            threshold, rule = best_f1_threshold(p, y), 'best pooled F1'
        rule += ' at the recorded resolution'
    else:
        rule = 'given'
    print(f'held-out evaluation, {len(blocks)} folds by recording; leg threshold '
          f'{threshold:.3f} ({rule})')
    print(f'{"held out":44s} {"resolution":>10s} {"legs":>5s} {"recall":>7s} '
          f'{"precision":>9s} {"false legs/neg. scan":>20s}')
    per_fold, pooled = [], {}
    for i, block in enumerate(blocks):
        row = {'held_out': sorted(block)}
        for name, t in tables.items():
            sel, p = held[name][i]
            row[name] = s = scores(p, t.y[sel], t.leg[sel], threshold,
                                   t.count(t.labelled_legs, block),
                                   t.count(t.negative_scans, block))
            _print_row(_short(block), name, s)
        per_fold.append(row)
    for name, t in tables.items():
        rows = np.concatenate([np.flatnonzero(sel) for sel, _ in held[name]])
        p = np.concatenate([p for _, p in held[name]])
        pooled[name] = s = scores(p, t.y[rows], t.leg[rows], threshold,
                                  sum(t.labelled_legs.values()),
                                  sum(t.negative_scans.values()))
        _print_row('all folds pooled', name, s)
    return threshold, {'folds': per_fold, 'pooled': pooled}


def _within(t: ClusterTable, max_range: float) -> np.ndarray:
    """Clusters of ``t`` the detector classifies: within ``max_range``."""
    return t.X[:, FEATURE_NAMES.index('distance')] <= max_range


def _short(block) -> str:
    names = sorted(g.replace('_extracted.bag', '').replace('.bag', '').replace('neg:', '')
                   for g in block)
    return ', '.join(names)


def _print_row(label: str, name: str, s: dict) -> None:
    print(f'{label[:44]:44s} {name:>10s} {s["labelled_legs"]:5d} {s["recall"]:7.3f} '
          f'{s["precision"]:9.3f} {s["false_legs_per_negative_scan"]:20.3f}')


if __name__ == '__main__':
    from laser_tracker.tools.cli import main

    sys.exit(main(['train-detector'] + sys.argv[1:]))
