"""People from the shape of their legs in one scan (no motion needed).

The occupancy-grid method sees what moves; a person standing still, or walking along with
the robot, is invisible to it. This detector finds people in a single scan:

1. :func:`laser_tracker.core.segmentation.segment` splits the scan into clusters by jump
   distance (the scan's segments, ``segments.*``) and describes each cluster's shape
   (features independent of the beam density);
2. a small gradient-boosted tree ensemble (:class:`LegClassifier`, trained offline by
   ``laser-tracker train-detector`` with scikit-learn, evaluated here by a compiled kernel)
   gives each cluster a leg probability;
3. legs become people (:meth:`PersonDetector.detect`): two legs at most ``pair_distance``
   apart are one person at their midpoint, the pairs chosen greedily by their mean
   probability, each leg used once; the second leg of a pair needs only
   ``partner_threshold``. A leg left alone is a person too when its probability reaches
   ``single_leg_threshold``: its other leg is then taken to be hidden (behind it, the usual
   case when a person walks radially, or behind something nearer), the person placed
   ``single_leg_offset`` behind the leg and its confidence scaled by ``single_leg_weight``.
   A lone leg within ``pair_distance`` of a person already found adds nothing.

Output, :class:`PersonDetections` (scanner frame, metres): per person ``xy``,
``confidence`` in [0, 1] (a pair: the mean of its legs' probabilities) and the indices of
its legs; per classified cluster (diagnostics) ``leg_xy``, ``leg_probability``,
``occluded`` ends and ``is_leg``.

The model file (``.npz``, :func:`load_model`) holds the trees as complete binary trees of
one depth (``feature``, ``threshold``, ``value`` arrays) and a JSON header naming the format
version and the feature set; a file that is missing, damaged, of another format version or
trained on other features raises :class:`DetectorModelError` naming the file, so a node can
log it and go on with the motion method alone.
"""
from __future__ import annotations

import json
import logging
import math
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from laser_tracker.config import param
from laser_tracker.core import jit
from laser_tracker.core.jit import pairwise_sum
from laser_tracker.core.detections import Rows
from laser_tracker.core.scan import Scan
from laser_tracker.core.segmentation import (CLEARANCE, FEATURE_NAMES, FEATURE_SET,
                                             MAX_WINDOW_ANGLE, Clusters, SegmentConfig,
                                             _clusters, as_clusters, closes_circle,
                                             kernel_arguments)
from laser_tracker.errors import InputFileError

log = logging.getLogger(__name__)

MODEL_FORMAT = 'laser_tracker.leg_classifier'
MODEL_VERSION = 1
PACKAGED_MODEL = Path(__file__).resolve().parents[1] / 'models' / 'person_detector.npz'
MAX_DEPTH = 12


class DetectorModelError(InputFileError):
    """A person-detector model file that cannot be used (missing, damaged, other version or
    feature set); the message names the file and what is wrong."""


# ------------------------------------------------------------------------ the classifier


class LegClassifier:
    """Gradient-boosted trees, evaluated by a kernel: ``predict_proba(features) -> (k,)``.

    Every tree is complete to ``depth``: node ``i`` has children ``2i+1`` (left, taken when
    ``x[feature] <= threshold``) and ``2i+2``; the ``2**depth`` leaves follow the
    ``2**depth - 1`` inner nodes. Features are compared as float32, as scikit-learn does, and
    the leaves added as numpy adds them, so the probabilities equal its ``predict_proba`` on
    the same features.
    """

    def __init__(self, feature: np.ndarray, threshold: np.ndarray, value: np.ndarray,
                 bias: float, meta: dict[str, Any] | None = None, path: str = ''):
        self.feature = np.ascontiguousarray(feature, dtype=np.intp)
        self.threshold = np.ascontiguousarray(threshold, dtype=np.float64)
        self.value = np.ascontiguousarray(value, dtype=np.float64)
        self.bias = float(bias)
        self.meta = dict(meta or {})
        self.path = path
        trees, inner = self.feature.shape
        self.depth = int(inner + 1).bit_length() - 1
        self.n_trees = trees

    @property
    def recommended_threshold(self) -> float:
        return float(self.meta.get('threshold', 0.5))

    @property
    def arrays(self) -> tuple:
        """The trees as :func:`_decision` reads them."""
        return self.feature, self.threshold, self.value, self.bias

    def decision_function(self, features: np.ndarray) -> np.ndarray:
        """Raw scores (log-odds) of the rows of ``features`` (k, len(FEATURE_NAMES))."""
        return _decision(np.ascontiguousarray(features, dtype=np.float64), *self.arrays)

    def predict_proba(self, features: np.ndarray) -> np.ndarray:
        """Leg probability of each row of ``features``."""
        return probability(self.decision_function(features))


def probability(z: np.ndarray) -> np.ndarray:
    """The probability of raw scores ``z``: ``1 / (1 + exp(-clip(z, -50, 50)))``."""
    return _logistic(_exponents(z))


def _logistic(w: np.ndarray) -> np.ndarray:
    """``1 / (1 + exp(w))``, in place: numpy's exp (its SIMD exp, kept bit for bit; numba's
    differs in the last bit now and then)."""
    np.exp(w, out=w)
    w += 1.0
    return np.divide(1.0, w, out=w)


@jit.kernel
def _exponents(z):
    """``-clip(z, -50, 50)``, a new array."""
    out = np.empty(z.size)
    for i in range(z.size):
        out[i] = -min(max(z[i], -50.0), 50.0)
    return out


@jit.kernel
def _decision(features, feature, threshold, value, bias):
    """``bias`` plus the leaf of every tree reached by each row of ``features`` (the
    leaves summed pairwise, as numpy sums a row)."""
    trees, inner = feature.shape
    out = np.empty(features.shape[0])
    leaves = np.empty(trees)
    for r in range(features.shape[0]):
        for t in range(trees):
            node = 0
            while node < inner:
                x = np.float64(np.float32(features[r, feature[t, node]]))
                node = 2 * node + (2 if x > threshold[t, node] else 1)
            leaves[t] = value[t, node - inner]
        out[r] = bias + pairwise_sum(leaves, 0, trees)
    return out


@jit.kernel
def _classified(ranges, cos, sin, valid_min, range_max, da, jump, min_points, max_width,
                max_range, closed, feature, threshold, value, bias):
    """The scan's segments (``segmentation._clusters``) and the exponents of their leg
    probabilities (:func:`_exponents` of their raw scores), in one call."""
    clusters = _clusters(ranges, cos, sin, valid_min, range_max, da, jump, min_points,
                         max_width, max_range, closed)
    return clusters, _exponents(_decision(clusters[3], feature, threshold, value, bias))


def save_model(path: str | Path, classifier: LegClassifier) -> None:
    """Write ``classifier`` as a model file (the header records format and feature set)."""
    meta = dict(classifier.meta)
    meta.update(format=MODEL_FORMAT, version=MODEL_VERSION, feature_set=FEATURE_SET,
                feature_names=list(FEATURE_NAMES), depth=classifier.depth,
                n_trees=classifier.n_trees, bias=classifier.bias)
    with open(path, 'wb') as f:
        np.savez_compressed(f, header=np.array(json.dumps(meta, sort_keys=True)),
                            feature=classifier.feature.astype(np.int16),
                            threshold=classifier.threshold,
                            value=classifier.value)


def load_model(path: str | Path = '') -> LegClassifier:
    """The classifier in ``path`` ('' = the packaged model); DetectorModelError if unusable."""
    path = Path(path) if str(path) else PACKAGED_MODEL
    if not path.is_file():
        raise DetectorModelError(path, 'no such model file' if not path.exists()
                                 else 'not a file')
    try:
        with open(path, 'rb') as f:
            magic = f.read(4)
    except OSError as exc:
        raise DetectorModelError(path, f'cannot read: {exc.strerror or exc}') from None
    if magic != b'PK\x03\x04':
        raise DetectorModelError(path, 'not a model file (.npz, a zip archive): '
                                 + ('empty' if not magic else 'other content'))
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {name: data[name] for name in data.files}
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile,
            zipfile.LargeZipFile) as exc:
        raise DetectorModelError(path, f'damaged or truncated model file ({exc})') from None
    except Exception as exc:  # noqa: BLE001 - zlib.error and others from a damaged archive
        raise DetectorModelError(path, f'damaged model file ({type(exc).__name__}: {exc})') \
            from None
    missing = [k for k in ('header', 'feature', 'threshold', 'value') if k not in arrays]
    if missing:
        raise DetectorModelError(path, f'not a {MODEL_FORMAT} file (no {", ".join(missing)})')
    try:
        meta = json.loads(str(arrays['header']))
    except ValueError as exc:
        raise DetectorModelError(path, f'unreadable header ({exc})') from None
    if not isinstance(meta, dict):
        raise DetectorModelError(path, 'unreadable header (not a JSON object)')
    if meta.get('format') != MODEL_FORMAT:
        raise DetectorModelError(path, f'not a {MODEL_FORMAT} file '
                                 f'(format {meta.get("format")!r})')
    if meta.get('version') != MODEL_VERSION:
        raise DetectorModelError(path, f'model format version {meta.get("version")!r}; this '
                                 f'laser_tracker reads version {MODEL_VERSION}: retrain it '
                                 '(laser-tracker train-detector)')
    if meta.get('feature_set') != FEATURE_SET or meta.get('feature_names') != \
            list(FEATURE_NAMES):
        names = meta.get('feature_names')
        count = len(names) if isinstance(names, list) else '?'
        raise DetectorModelError(path, f'trained on feature set {meta.get("feature_set")!r} '
                                 f'({count} features), this laser_tracker computes '
                                 f'{FEATURE_SET!r} ({len(FEATURE_NAMES)} features): retrain '
                                 'it (laser-tracker train-detector)')
    feature, threshold, value = arrays['feature'], arrays['threshold'], arrays['value']
    problem = _check_arrays(feature, threshold, value)
    try:
        bias = float(meta.get('bias'))
    except (TypeError, ValueError):
        bias = float('nan')
    if problem is None and not np.isfinite(bias):
        problem = f'bias is {meta.get("bias")!r}'
    if problem:
        raise DetectorModelError(path, f'inconsistent model: {problem}')
    return LegClassifier(feature, threshold, value, bias, meta, str(path))


def _check_arrays(feature, threshold, value) -> str | None:
    if feature.ndim != 2 or threshold.shape != feature.shape or value.ndim != 2 or \
            value.shape[0] != feature.shape[0] or feature.shape[0] == 0:
        return (f'array shapes feature {feature.shape}, threshold {threshold.shape}, '
                f'value {value.shape}')
    inner = feature.shape[1]
    depth = int(inner + 1).bit_length() - 1
    if inner != 2 ** depth - 1 or value.shape[1] != 2 ** depth or not 1 <= depth <= MAX_DEPTH:
        return f'{inner} inner nodes and {value.shape[1]} leaves per tree is not a complete tree'
    if not (np.issubdtype(feature.dtype, np.integer) and np.issubdtype(threshold.dtype,
                                                                       np.floating)
            and np.issubdtype(value.dtype, np.floating)):
        return f'array types {feature.dtype}, {threshold.dtype}, {value.dtype}'
    if feature.min() < 0 or feature.max() >= len(FEATURE_NAMES):
        return f'feature index outside 0..{len(FEATURE_NAMES) - 1}'
    if np.isnan(threshold).any() or not np.isfinite(value).all():
        return 'NaN or infinite values'
    return None


# ------------------------------------------------------------------------ people from legs


@dataclass(frozen=True)
class PersonDetectorConfig:
    """People from the shape of their legs in one scan (``person_detector.*``)."""

    enabled: bool = param(True, 'Detect people by the shape of their legs in each scan.')
    model: str = param('', "Model file (laser-tracker train-detector); '' = the model shipped "
                       'with the package (trained on the leg_tracker recordings).')
    threshold: float = param(0.0, 'Leg probability from which a cluster is a leg; 0 = the '
                             'threshold chosen at training (recorded in the model file).',
                             min=0.0, max=1.0)
    partner_threshold: float = param(0.0, 'Leg probability the second leg of a pair needs; '
                                     '0 = half the leg threshold.', min=0.0, max=1.0)
    single_legs: bool = param(True, 'A leg with no partner is a person (its other leg '
                              'hidden behind it or behind something nearer).')
    single_leg_threshold: float = param(0.0, 'Leg probability a leg alone needs to be a '
                                        'person; 0 = the leg threshold.', min=0.0, max=1.0)
    single_leg_weight: float = param(0.5, "A lone leg's person confidence is its "
                                     'probability times this.', min=0.0, max=1.0)
    single_leg_offset: float = param(0.1, "A lone leg's person lies this far behind the leg "
                                     '(m, away from the scanner), between it and the hidden '
                                     'leg.', min=0.0, max=1.0)
    pair_distance: float = param(0.6, 'Two legs at most this far apart (m, between cluster '
                                 'centres) are one person: a stride at knee height.',
                                 min=0.05, max=2.0)
    max_range: float = param(12.0, 'Segments (segments.*) farther than this (m) are not '
                             'classified: as far as the grid reaches (half its diagonal, '
                             '11.3 m at grid.size 16), where a person\'s track can still be '
                             'confirmed and followed; beyond it, a leg shape alone would only '
                             'make tracks that nothing confirms.', min=0.1, max=100.0)
    max_legs: int = param(32, 'At most this many leg candidates per scan (the most probable) '
                          'are paired: bounds the work in a crowd.', min=2, max=1000)
    view_edge: bool = param(
        True, 'A segment that reaches the edge of the field of view (its first or last point '
        'is the first or last beam of a scanner that does not see all around) may go on '
        'beyond it, so its shape says little: its leg probability counts at most as much as '
        'a second leg needs (partner_threshold). It still completes a person with a whole '
        'leg beside it, but is no person alone: the wall the robot drives along, cut where '
        'the field of view ends, keeps its place beside the robot and looks like a lone leg. '
        'false = classified as any other segment.')
    masked_edge: bool = param(
        True, 'A segment that runs into a return the self-mask took out (beyond one of its '
        'ends, the next beam that measured anything, within 0.15 m, returned the robot\'s '
        'own body or a mixed return at a nearer edge, nearer than that end) may go on behind '
        'it: as at the edge of the field of view, its leg probability counts at most as much '
        'as a second leg needs (partner_threshold). It still completes a person with a whole '
        'leg beside it, but is no person alone. false = classified as any other segment.')


@dataclass
class PersonDetections(Rows):
    """People found in one scan (scanner frame) and the clusters behind them.

    Per person: ``xy`` (p, 2) metres, ``confidence`` (p,) in [0, 1], ``legs`` (p, 2) indices
    into the leg arrays (second = -1 for a lone leg). Per classified cluster: ``leg_xy``
    (k, 2) centroid, ``leg_probability`` (k,), ``is_leg`` (k,) above the threshold,
    ``occluded`` (k, 2) a nearer return beside its first / last end; ``clusters`` all of the
    classified clusters' arrays and features (:class:`~laser_tracker.core.segmentation.
    Clusters`).
    """

    stamp: float
    frame_id: str
    xy: np.ndarray
    confidence: np.ndarray
    legs: np.ndarray
    leg_xy: np.ndarray
    leg_probability: np.ndarray
    is_leg: np.ndarray
    occluded: np.ndarray
    clusters: Clusters | None = field(default=None, repr=False)

    @classmethod
    def empty(cls, stamp: float = 0.0, frame_id: str = 'laser') -> PersonDetections:
        return cls(stamp=float(stamp), frame_id=frame_id, xy=np.zeros((0, 2)),
                   confidence=np.zeros(0), legs=np.zeros((0, 2), dtype=np.intp),
                   leg_xy=np.zeros((0, 2)), leg_probability=np.zeros(0),
                   is_leg=np.zeros(0, dtype=bool), occluded=np.zeros((0, 2), dtype=bool))


def cut_by_view(scan: Scan, clusters: Clusters) -> np.ndarray:
    """Per cluster: it reaches the edge of the field of view (its first or last point is
    the scan's first or last beam: it may go on beyond); never for a scan that closes the
    circle."""
    if closes_circle(scan.n_beams, float(scan.angle_increment)):
        return np.zeros(len(clusters), bool)
    return (clusters.first == 0) | (clusters.last == scan.n_beams - 1)


def cut_by_mask(scan: Scan, clusters: Clusters, masked: np.ndarray) -> np.ndarray:
    """Per cluster: beyond its first or last end, the next beam that measured anything
    (beams without a return say nothing) returned what the self-mask took out of ``scan``
    (``masked``, per beam; NaN, or anything but a positive finite range: none), nearer than
    that end and within the clearance window beside it (``segmentation.CLEARANCE`` at the
    end's range): the segment may go on behind the robot's body or behind the edge that a
    mixed return marks."""
    out = np.zeros(len(clusters), np.bool_)
    if np.shape(masked) != (scan.n_beams,) or not len(clusters):
        return out
    _cut_by_mask(scan.ranges, np.ascontiguousarray(masked, dtype=float), clusters.first,
                 clusters.last, max(scan.range_min, 1e-6), float(scan.range_max),
                 abs(float(scan.angle_increment)),
                 closes_circle(scan.n_beams, float(scan.angle_increment)), out)
    return out


@jit.kernel
def _cut_by_mask(ranges, masked, first, last, valid_min, range_max, da, closed, out):
    """:func:`cut_by_mask` into ``out``: from each end, outwards over the window's beams
    (around the seam when the scan ``closed`` the circle) to the first that measured
    anything."""
    n = ranges.size
    for c in range(first.size):
        for e in range(2):
            end = first[c] if e == 0 else last[c]
            step = -1 if e == 0 else 1
            r = ranges[end]
            span = int(min(math.ceil(CLEARANCE / (r * da)), math.ceil(MAX_WINDOW_ANGLE / da)))
            for j in range(1, span + 1):
                beam = end + step * j
                if closed:
                    beam = beam % n
                elif beam < 0 or beam >= n:
                    break
                m = masked[beam]
                if m > 0.0 and m < np.inf:                  # taken out: it decides
                    if m < r:
                        out[c] = True
                    break
                if ranges[beam] >= valid_min and ranges[beam] < range_max:
                    break                                   # a return of the scan
    return out


class PersonDetector:
    """``PersonDetector(config).detect(scan) -> PersonDetections``.

    The model is loaded when the detector is made (DetectorModelError if it cannot be; not
    at all when ``enabled`` is false); ``classifier`` may be given instead. The clusters it
    classifies are the scan's segments (``segments``, ``core.segmentation``).
    """

    def __init__(self, config: PersonDetectorConfig | None = None,
                 classifier: LegClassifier | None = None,
                 segments: SegmentConfig | None = None):
        self.config = config or PersonDetectorConfig()
        self.segments = segments or SegmentConfig()
        c = self.config
        if classifier is None:
            classifier = load_model(c.model) if c.enabled else \
                LegClassifier(np.zeros((1, 1)), np.full((1, 1), np.inf), np.zeros((1, 2)), 0.0)
        self.classifier = classifier
        self.threshold = c.threshold or self.classifier.recommended_threshold
        self.partner_threshold = c.partner_threshold or 0.5 * self.threshold
        self.single_leg_threshold = c.single_leg_threshold or self.threshold
        jump = self.segments.jump_distance
        trained = self.classifier.meta.get('segmentation', {}).get('jump_distance')
        if trained is not None and abs(float(trained) - jump) > 1e-9:
            log.warning('person detector: segments.jump_distance %.3f differs from the %.3f '
                        'the model %s was trained with', jump, float(trained),
                        self.classifier.path)

    def classify(self, scan: Scan) -> tuple[Clusters, np.ndarray]:
        """The scan's segments within ``max_range`` and their leg probabilities (one kernel
        call)."""
        s = self.segments
        args, seam = kernel_arguments(scan, s.jump_distance, s.min_points, s.max_width,
                                      self.config.max_range)
        raw, w = _classified(*args, *self.classifier.arrays)
        return as_clusters(raw, seam), _logistic(w)

    def detect(self, scan: Scan, masked: np.ndarray | None = None) -> PersonDetections:
        """People in ``scan``; ``masked``: per beam, the return that the self-mask took out
        of ``scan`` (NaN: none; see ``masked_edge``)."""
        c = self.config
        if not c.enabled:
            return PersonDetections.empty(scan.stamp, scan.frame_id)
        clusters, prob = self.classify(scan)
        if len(clusters) and (c.view_edge or c.masked_edge):
            cut = np.zeros(len(clusters), bool)
            if c.view_edge:
                cut |= cut_by_view(scan, clusters)
            if c.masked_edge and masked is not None:
                cut |= cut_by_mask(scan, clusters, masked)
            prob = np.where(cut, np.minimum(prob, self.partner_threshold), prob)
        xy = clusters.xy
        is_leg = prob >= self.threshold
        persons, conf, legs = _people(xy, prob, self.threshold, self.partner_threshold,
                                      self.single_leg_threshold, c.pair_distance,
                                      c.single_legs, c.single_leg_weight, c.single_leg_offset,
                                      c.max_legs)
        return PersonDetections(stamp=float(scan.stamp), frame_id=scan.frame_id, xy=persons,
                                confidence=conf, legs=legs, leg_xy=xy, leg_probability=prob,
                                is_leg=is_leg, occluded=clusters.occluded, clusters=clusters)


def _people(xy, prob, leg_threshold, partner_threshold, single_threshold, pair_distance,
            single_legs, weight, offset, max_legs):
    """Pairs of legs, then lone legs, as people (see the module docstring): positions,
    confidences, legs (indices into the clusters; -1: the hidden leg of a lone one)."""
    return _pair_legs(xy, prob, float(leg_threshold), float(partner_threshold),
                      float(single_threshold), float(pair_distance), bool(single_legs),
                      float(weight), float(offset), int(max_legs), 2.0)


@jit.kernel
def _pair_legs(xy, prob, leg_threshold, partner_threshold, single_threshold, pair_distance,
               single_legs, weight, offset, max_legs, two):
    """:func:`_people`. The candidates: clusters reaching the partner threshold (or the
    lone-leg one), at most ``max_legs`` (the most probable). Pairs within ``pair_distance``
    of which one reaches the leg threshold, greedily by their summed probability (ties: in
    candidate order), each leg used once; then each lone leg reaching ``single_threshold``,
    unless within ``pair_distance`` of a pair. Numbers as the former Python formulation gave
    them: ``jit.python_hypot`` is ``math.hypot``, and a square is ``pow(d, two)`` (libm's pow,
    as Python's ``d ** 2``; ``two`` is 2.0, an argument so that it is not folded into
    ``d * d``)."""
    lowest = min(partner_threshold, single_threshold if single_legs else 1.0)
    cand = np.flatnonzero(prob >= lowest)
    if cand.size > max_legs:
        cand = cand[np.argsort(-prob[cand], kind='mergesort')[:max_legs]]
    n = cand.size
    reach = pair_distance * pair_distance
    keys, first, second = np.empty(n * n), np.empty(n * n, np.intp), np.empty(n * n, np.intp)
    m = 0
    for a in range(n):
        pa = prob[cand[a]]
        if pa < partner_threshold:
            continue
        xa, ya = xy[cand[a], 0], xy[cand[a], 1]
        for b in range(a + 1, n):
            pb = prob[cand[b]]
            if pb < partner_threshold or (pa < leg_threshold and pb < leg_threshold):
                continue
            dx, dy = xa - xy[cand[b], 0], ya - xy[cand[b], 1]
            if dx * dx + dy * dy <= reach:
                keys[m], first[m], second[m] = -(pa + pb), a, b
                m += 1
    order = np.argsort(keys[:m], kind='mergesort')
    used = np.zeros(n, np.bool_)
    out = np.empty((n, 3))
    legs = np.full((n, 2), -1, np.intp)
    p = 0
    for o in order:
        a, b = first[o], second[o]
        if not (used[a] or used[b]):
            used[a] = used[b] = True
            ca, cb = cand[a], cand[b]
            out[p, 0] = 0.5 * (xy[ca, 0] + xy[cb, 0])
            out[p, 1] = 0.5 * (xy[ca, 1] + xy[cb, 1])
            out[p, 2] = 0.5 * (prob[ca] + prob[cb])
            legs[p, 0], legs[p, 1] = ca, cb
            p += 1
    paired = p
    for a in range(n if single_legs else 0):
        ca = cand[a]
        if used[a] or prob[ca] < single_threshold:
            continue
        x, y = xy[ca, 0], xy[ca, 1]
        scale = 1.0 + offset / max(jit.python_hypot(x, y), 1e-6)
        x, y = x * scale, y * scale
        alone = True
        for q in range(paired):
            if math.pow(x - out[q, 0], two) + math.pow(y - out[q, 1], two) <= reach:
                alone = False
                break
        if alone:
            out[p, 0], out[p, 1], out[p, 2] = x, y, weight * prob[ca]
            legs[p, 0] = ca
            p += 1
    return out[:p, :2].copy(), out[:p, 2].copy(), legs[:p].copy()
