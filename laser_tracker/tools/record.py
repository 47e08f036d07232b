"""``laser-tracker replay BAG --record OUT``: a rosbag2 recording of what the tracker saw.

One set of messages per replayed scan, every one logged at the scan's header stamp and
stamped with it exactly, as the nodes publish them (the same functions of
``laser_tracker.conversions``), so that Foxglove, RViz (``ros2 bag play``) or a program steps
through the run scan by scan:

==========================  =====================================  ===========================
topic                       type                                   content
==========================  =====================================  ===========================
``/scan``                   sensor_msgs/LaserScan                  the input scan, whatever its
                                                                   topic in the input
``/tf``                     tf2_msgs/TFMessage                     odom -> base (the odometry's
                                                                   child frame; the scanner's
                                                                   frame without odometry);
                                                                   map -> odom with ground truth
``/tf_static``              tf2_msgs/TFMessage (latched)           base -> scanner (the mount)
``/ego_motion``,            nav_msgs/Odometry,                     as the ``ego_motion`` node
``/ego_motion/status``      diagnostic_msgs/DiagnosticArray
``/grid``,                  nav_msgs/OccupancyGrid                 the occupancy grid and the
``/grid/difference``                                               difference map, scanner frame
                                                                   (every ``grids``-th scan)
``/blobs``                  visualization_msgs/MarkerArray         as the ``detection`` node,
                                                                   without its ``view``
``/hypotheses``,            visualization_msgs/MarkerArray         as the ``tracking`` node
``/tracks``,
``/tracks/markers``
``/ground_truth``           visualization_msgs/MarkerArray         simulated truth (map frame)
                                                                   or annotated people (scanner
                                                                   frame), when the input has it
``/ground_truth/platform``  nav_msgs/Odometry                      passed through
``/evaluation``             visualization_msgs/MarkerArray         with ``--evaluate``: CLEAR MOT
                                                                   per frame
==========================  =====================================  ===========================

Frames: ``odom`` (tracks, blobs, ego-motion), the scanner's (scans, grids), ``map`` (simulated
ground truth: map -> odom is the correction ``laser-tracker evaluate`` applies, so the truth
lies where the tracker is scored against it).

Size: the messages are built by the nodes' functions with :data:`FACTORY`, which stores
positions to :data:`POSITION_STEP`, orientations at float32 precision and covariances to 3
significant digits (``conversions.recording_factory``), and the mcap file is rewritten
compact, in time order and without message indexes (``tools.compact_mcap``). The grids are
the bulk of what is left (two 160 x 160 grids per scan): by default every
:data:`DEFAULT_GRID_EVERY`-th scan has them, ``grids=1`` (``--record-grids every``) gives all.
sqlite3 storage is not compacted.

The recording appears whole or not at all (``tools.bag.BagWriter``): an existing path is
refused without ``overwrite``, an unwritable one fails before the replay starts, and a write
that fails (a full disk) is one error line with nothing left behind.
"""
from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from laser_tracker.conversions import (OCCUPANCY_OF_CELL, MovingObject, PlanarTransform,
                                       detections_to_marker_array, difference_occupancy,
                                       ego_motion_to_msgs,
                                       evaluation_markers, objects_to_marker_array,
                                       occupancy_grid_msg, recording_factory, restamp_ns,
                                       scan_to_msg, time_msg, tracker_msgs, transforms_to_msg)
from laser_tracker.core.detections import View
from laser_tracker.core.geometry import compose, interpolate_poses, inverse
from laser_tracker.errors import LaserTrackerError
from laser_tracker.tools.bag import (FACTORY as BAG_FACTORY, GROUND_TRUTH_TOPIC, LATCHED_QOS,
                                     PLATFORM_TRUTH_TOPIC, TF_STATIC_TOPIC, TYPESTORE,
                                     BagWriter)

#: Positions in the recording are multiples of this (m; also m/s, rad/s).
POSITION_STEP = 2.0 ** -10
#: The recording's messages: built as the nodes build them, positions rounded to
#: POSITION_STEP, orientations to float32 precision, covariances to 3 significant digits.
FACTORY = recording_factory(TYPESTORE, POSITION_STEP)

log = logging.getLogger(__name__)

SCAN_TOPIC = '/scan'
TF_TOPIC = '/tf'
GRID_TOPIC = '/grid'
DIFFERENCE_TOPIC = '/grid/difference'
EGO_TOPIC = '/ego_motion'
EGO_STATUS_TOPIC = '/ego_motion/status'
BLOBS_TOPIC = '/blobs'
HYPOTHESES_TOPIC = '/hypotheses'
TRACKS_TOPIC = '/tracks'
TRACK_MARKERS_TOPIC = '/tracks/markers'
EVALUATION_TOPIC = '/evaluation'
MAP_FRAME = 'map'

#: Every topic a recording may hold, with its type (the layouts in config/ name these).
TOPICS = {
    SCAN_TOPIC: 'sensor_msgs/msg/LaserScan',
    TF_TOPIC: 'tf2_msgs/msg/TFMessage',
    TF_STATIC_TOPIC: 'tf2_msgs/msg/TFMessage',
    EGO_TOPIC: 'nav_msgs/msg/Odometry',
    EGO_STATUS_TOPIC: 'diagnostic_msgs/msg/DiagnosticArray',
    GRID_TOPIC: 'nav_msgs/msg/OccupancyGrid',
    DIFFERENCE_TOPIC: 'nav_msgs/msg/OccupancyGrid',
    BLOBS_TOPIC: 'visualization_msgs/msg/MarkerArray',
    HYPOTHESES_TOPIC: 'visualization_msgs/msg/MarkerArray',
    TRACKS_TOPIC: 'visualization_msgs/msg/MarkerArray',
    TRACK_MARKERS_TOPIC: 'visualization_msgs/msg/MarkerArray',
    GROUND_TRUTH_TOPIC: 'visualization_msgs/msg/MarkerArray',
    PLATFORM_TRUTH_TOPIC: 'nav_msgs/msg/Odometry',
    EVALUATION_TOPIC: 'visualization_msgs/msg/MarkerArray',
}

#: Grids on every N-th scan by default: on every scan they would be most of a recording.
DEFAULT_GRID_EVERY = 50
GRID_CHOICES = 'every, none or N (every N-th scan)'


def grid_every(text: str | int) -> int:
    """``--record-grids`` -> every how many scans the grids are written (0: never)."""
    word = str(text).strip().lower()
    if word in ('every', 'all'):
        return 1
    if word in ('none', 'off', '0'):
        return 0
    try:
        every = int(word)
    except ValueError:
        every = -1
    if every < 1:
        raise LaserTrackerError(f'--record-grids {text!r}: expected {GRID_CHOICES}')
    return every


@dataclass(frozen=True)
class RecordOptions:
    """What ``replay --record`` writes: where, in which storage, grids every ``grids`` scans
    (1: all, 0: none), and whether the evaluation's verdicts are added."""

    path: Path
    storage: str = 'mcap'
    overwrite: bool = False
    grids: int = DEFAULT_GRID_EVERY
    evaluate: bool = False


class RunRecorder:
    """Writes the recording of one replay (the module doc says what).

    ``with RunRecorder(options) as rec:`` opens the output (an existing or unwritable path
    fails here, before any work); then ``start(...)`` once the recording's frames are known,
    ``scan_message`` for every input scan, ``passthrough`` for the ground-truth topics,
    ``step`` for every replayed scan and, last, ``evaluation``.
    """

    def __init__(self, options: RecordOptions):
        self.options = options
        self.path = Path(options.path)
        self.counts: dict[str, int] = {}
        self._bag: BagWriter | None = None
        self._static_done = False
        self._stamps: list[tuple[float, int]] = []      # (stamp s, stamp ns) of each step
        self.base_frame: str | None = None
        self.scan_frame = ''
        self.mount = np.zeros(3)
        self.mirrored = False
        self.resolution = 0.1
        self._truth: tuple[np.ndarray, np.ndarray] | None = None   # platform truth, scanner
        self._annotations = None     # (annotations.Annotations, {scan index: its rows})
        self._passthrough: set[str] = set()

    # ---------------------------------------------------------------- output
    def __enter__(self) -> RunRecorder:
        try:                    # BagWriter checks the output first (tools.atomic.check_output)
            self._bag = BagWriter(self.path, storage=self.options.storage,
                                  overwrite=self.options.overwrite, compact=True).__enter__()
        except OSError as exc:
            raise LaserTrackerError(f'{self.path}: cannot write the recording here: '
                                    f'{exc.strerror or exc}') from None
        return self

    def __exit__(self, exc_type, exc, tb):
        try:
            self._bag.__exit__(exc_type, exc, tb)
        except OSError as err:          # closing failed: a full disk; nothing is left
            raise LaserTrackerError(f'{self.path}: recording not written: '
                                    f'{err.strerror or err}') from None
        return False

    def _write(self, topic: str, msg, ns: int, qos=()) -> None:
        try:
            self._bag.write(topic, msg, int(ns), qos)
        except OSError as err:
            raise LaserTrackerError(f'{self.path}: recording not written: '
                                    f'{err.strerror or err}') from None
        self.counts[topic] = self.counts.get(topic, 0) + 1

    # ---------------------------------------------------------------- inputs
    def start(self, bag: Path, info: dict, scan_topic: str, mount, resolution: float) -> None:
        """What the input holds: its topics (``tools.bag.topics``), the replayed scan topic,
        the mount used (``tools.mount.Mount``) and the grid's cell size."""
        from laser_tracker.tools.annotations import ANNOTATION_TOPIC
        from laser_tracker.tools.bag import read_platform_truth

        self.resolution = float(resolution)
        self.mount = np.array([mount.x, mount.y, mount.yaw], float)
        self.mirrored = bool(mount.mirrored)     # scans turned over: their intensities too
        self.base_frame = (mount.base_frame or '').strip('/') or None
        if PLATFORM_TRUTH_TOPIC in info and info[PLATFORM_TRUTH_TOPIC][1]:
            truth = read_platform_truth(bag)
            order = np.argsort(truth.stamps, kind='stable')
            scanner = np.array([compose(p, self.mount) for p in truth.poses[order]])
            self._truth = (truth.stamps[order], scanner.reshape(-1, 3))
            self._passthrough.add(PLATFORM_TRUTH_TOPIC)
            if GROUND_TRUTH_TOPIC in info:
                self._passthrough.add(GROUND_TRUTH_TOPIC)
        elif GROUND_TRUTH_TOPIC in info:
            log.warning('%s: %s is not recorded: without %s its frame %r is not connected to '
                        'the odometry frame', bag, GROUND_TRUTH_TOPIC, PLATFORM_TRUTH_TOPIC,
                        MAP_FRAME)
        if ANNOTATION_TOPIC in info and info[ANNOTATION_TOPIC][1]:
            from laser_tracker.tools.annotations import read_annotations
            from laser_tracker.tools.bag import read_scan_times

            ann = read_annotations(bag, ANNOTATION_TOPIC, read_scan_times(bag, scan_topic))
            if self.mirrored:
                ann = ann.mirrored()
            self._annotations = (ann, {int(k): np.flatnonzero(ann.scan == k)
                                       for k in np.unique(ann.scan)})

    @property
    def passthrough_topics(self) -> list[str]:
        """Input topics the replay hands to :meth:`passthrough`."""
        return sorted(self._passthrough)

    def wants_grids(self, scan_index: int) -> bool:
        every = self.options.grids
        return every > 0 and scan_index % every == 0

    def scan_message(self, index: int, intensities: np.ndarray, scan) -> None:
        """An input scan (``scan``, its ``core.scan.Scan``; ``intensities`` as received,
        :func:`intensities_of`), the ``index``-th of its topic: written as received (Jazzy
        definitions) with the annotations placed at it."""
        frame = scan.frame_id.strip('/')
        self.scan_frame = self.scan_frame or frame
        if self.mirrored:
            intensities = intensities[::-1]
        out = scan_to_msg(FACTORY, scan, intensities
                          if intensities.size == scan.n_beams else None)
        out.header.frame_id = frame
        self._write(SCAN_TOPIC, restamp_ns(FACTORY, out, scan.stamp_ns), scan.stamp_ns)
        if self._annotations is not None:
            a, at_scan = self._annotations
            rows = at_scan.get(index, np.zeros(0, np.intp))
            people = [MovingObject(int(a.obj_id[r]), float(a.x[r]), float(a.y[r]),
                                   extra={'kind': 'person'}) for r in rows]
            gt = objects_to_marker_array(FACTORY, people, scan.stamp, frame, 'ground_truth',
                                         color=(0.1, 0.8, 0.1, 0.8))
            self._write(GROUND_TRUTH_TOPIC, restamp_ns(FACTORY, gt, scan.stamp_ns),
                        scan.stamp_ns)

    def passthrough(self, topic: str, receive_ns: int, msg) -> None:
        """A ground-truth message, logged at its header stamp."""
        hdr = msg.markers[0].header if hasattr(msg, 'markers') and msg.markers else \
            getattr(msg, 'header', None)
        ns = receive_ns if hdr is None else \
            int(hdr.stamp.sec) * 1_000_000_000 + int(hdr.stamp.nanosec)
        self._write(topic, msg, ns)

    # ---------------------------------------------------------------- outputs
    def step(self, result, tracks) -> None:
        """Everything one replayed scan produced (``core.pipeline.StepResult`` and the
        tracker's ``Tracks`` after it)."""
        f = FACTORY
        scan, ego = result.scan, result.ego
        ns, stamp = scan.stamp_ns, float(result.stamp)
        self._stamps.append((stamp, ns))
        self._transforms(ego, stamp, ns)
        odometry, status = ego_motion_to_msgs(f, ego)
        self._write(EGO_TOPIC, odometry, ns)
        self._write(EGO_STATUS_TOPIC, status, ns)
        det = result.detection
        if det.grid is not None:
            self._write(GRID_TOPIC, restamp_ns(f, occupancy_grid_msg(
                f, OCCUPANCY_OF_CELL[det.grid], self.resolution, stamp, scan.frame_id), ns), ns)
            self._write(DIFFERENCE_TOPIC, restamp_ns(f, occupancy_grid_msg(
                f, difference_occupancy(det), self.resolution, stamp, scan.frame_id), ns), ns)
        found = det.detections
        # without the view: it repeats the recorded scan, and would double the recording
        self._write(BLOBS_TOPIC, restamp_ns(f, detections_to_marker_array(
            f, dataclasses.replace(found, view=View())), ns), ns)
        confirmed, hypotheses, markers = tracker_msgs(f, tracks, found.stamp, found.frame_id,
                                                      ns)
        self._write(HYPOTHESES_TOPIC, hypotheses, ns)
        self._write(TRACKS_TOPIC, confirmed, ns)
        self._write(TRACK_MARKERS_TOPIC, markers, ns)

    def _transforms(self, ego, stamp: float, ns: int) -> None:
        """/tf at this scan (odom -> base or scanner; map -> odom with ground truth), and
        /tf_static (base -> scanner) once."""
        odom, scanner = ego.frame_id, self.scan_frame or ego.child_frame_id.strip('/')
        base = self.base_frame if self.base_frame and self.base_frame != scanner else None
        pose = np.asarray(ego.pose, float)
        if not self._static_done and base is not None:
            mount = PlanarTransform(stamp, base, scanner, *self.mount)
            self._write(TF_STATIC_TOPIC, _stamped(transforms_to_msg(BAG_FACTORY, [mount]), ns),
                        ns, LATCHED_QOS)       # once: at full precision
        self._static_done = True
        child = base or scanner
        at = compose(pose, inverse(self.mount)) if base else pose
        transforms = [PlanarTransform(stamp, odom, child, *at)]
        if self._truth is not None:
            true = interpolate_poses(*self._truth, np.array([stamp]))[0]
            transforms.append(PlanarTransform(stamp, MAP_FRAME, odom,
                                              *compose(true, inverse(pose))))
        self._write(TF_TOPIC, _stamped(transforms_to_msg(FACTORY, transforms), ns), ns)

    def evaluation(self, ev) -> int:
        """``/evaluation``: per scored frame, CLEAR MOT's verdicts of ``ev``
        (``evaluate.Evaluation``: simulated ground truth, map frame; or annotated people,
        scanner frame). Returns how many frames were written."""
        from laser_tracker.tools.scoring import match_stamps, median_period

        if ev.scores is not None and ev.scores.verdicts is not None:
            verdicts, stamps, frame_id = ev.scores.verdicts, ev.truth.stamps, MAP_FRAME
        elif ev.annotated is not None and ev.annotated.verdicts is not None:
            verdicts, stamps = ev.annotated.verdicts, ev.annotated.frame_stamps
            frame_id = self.scan_frame
        else:
            raise LaserTrackerError('--evaluate: the recording has no ground truth or '
                                    'annotated people to score per frame')
        seconds = np.array([s for s, _ in self._stamps], float)
        order = np.argsort(seconds, kind='stable')
        scan_of_frame = match_stamps(np.asarray(stamps, float), seconds[order],
                                     0.25 * median_period(seconds))
        frames = 0
        for f, k in enumerate(scan_of_frame):
            if k < 0:
                continue
            stamp, ns = self._stamps[order[k]]
            rows = np.flatnonzero(verdicts.frame == f)
            kind = verdicts.kind[rows]
            match = rows[np.isin(kind, ('MATCH', 'SWITCH'))]
            msg = evaluation_markers(
                FACTORY, stamp, frame_id,
                np.hstack((verdicts.track_xy[match], verdicts.obj_xy[match])),
                verdicts.obj_xy[rows[kind == 'MISS']], verdicts.track_xy[rows[kind == 'FP']])
            self._write(EVALUATION_TOPIC, restamp_ns(FACTORY, msg, ns), ns)
            frames += 1
        return frames

    def summary(self) -> dict:
        """For summary.json: where, how, what (messages per topic)."""
        size = sum(p.stat().st_size for p in self.path.rglob('*') if p.is_file()) \
            if self.path.exists() else None
        return {'path': str(self.path), 'storage': self.options.storage,
                'grids_every': self.options.grids, 'bytes': size,
                'messages': dict(sorted(self.counts.items()))}


def intensities_of(msg) -> np.ndarray:
    """A LaserScan message's intensities as float32 (empty when it has none)."""
    return np.asarray(getattr(msg, 'intensities', ()), dtype=np.float32)


class RecordingProcess:
    """A :class:`RunRecorder` in a child process, with the same interface: the replay hands
    it each scan's results and goes on while the child builds, serialises, compresses and
    writes the messages, so that recording costs little more wall time than the replay on a
    machine with a second core.

    Calls that return something (``start``'s topics, ``evaluation``, ``summary``) wait for
    the child; the others are queued through a pipe (its buffer bounds what is in flight).
    The child ignores Ctrl-C: the replay decides, and leaving the ``with`` block with an
    exception (or dying) makes the child remove the partial recording. An error in the child
    (a full disk) is raised in the replay at its next call."""

    def __init__(self, options: RecordOptions):
        self.options = options
        self._conn = None
        self._proc = None
        self._topics: list[str] = []
        self._calls = 0
        self._summary: dict | None = None

    def __enter__(self) -> RecordingProcess:
        import multiprocessing

        ctx = multiprocessing.get_context('fork')
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(target=_serve, args=(self.options, child, self._conn),
                                 daemon=True, name='laser-tracker recorder')
        self._proc.start()
        child.close()
        try:
            self._call('__enter__')
        except (EOFError, OSError):
            raise LaserTrackerError(f'{self.options.path}: cannot write the recording: the '
                                    'recording process did not start') from None
        finally:
            if not self._proc.is_alive():
                self._proc.join()
        return self

    def __exit__(self, exc_type, exc, tb):
        try:
            if exc_type is None:
                self._summary = self._call('__exit__', None, None, None)
            else:          # the replay failed or was interrupted: nothing is left behind
                try:
                    self._call('__exit__', LaserTrackerError, LaserTrackerError('aborted'),
                               None)
                except (LaserTrackerError, RuntimeError):
                    pass        # the replay's own error is the one to report
        except (EOFError, OSError):
            if exc_type is None:
                raise LaserTrackerError(f'{self.options.path}: recording not written: the '
                                        'recording process ended unexpectedly') from None
        finally:
            self._conn.close()
            self._proc.join(timeout=10.0)
        return False

    def start(self, *args) -> None:
        self._topics = self._call('start', *args)

    @property
    def passthrough_topics(self) -> list[str]:
        return self._topics

    def wants_grids(self, scan_index: int) -> bool:
        return RunRecorder.wants_grids(self, scan_index)

    def scan_message(self, index: int, msg, scan) -> None:
        """As :meth:`RunRecorder.scan_message`, given the input message ``msg`` (only its
        intensities cross to the recording process)."""
        self._cast('scan_message', index, intensities_of(msg), scan)

    def passthrough(self, topic: str, receive_ns: int, msg) -> None:
        self._cast('passthrough', topic, receive_ns, msg)

    def step(self, result, tracks) -> None:
        det = result.detection
        self._cast('step', StepRecord(result.scan, result.ego, result.stamp,
                                      dataclasses.replace(det, persons=None)), tracks)

    def evaluation(self, ev) -> int:
        return self._call('evaluation', ev)

    def summary(self) -> dict:
        """As :meth:`RunRecorder.summary`; after the ``with`` block, of the written file."""
        return self._summary if self._summary is not None else self._call('summary')

    def _cast(self, name: str, *args) -> None:
        while self._conn.poll():              # the child failed: say so now
            self._answer(self._conn.recv())
        self._conn.send((None, name, args))

    def _call(self, name: str, *args):
        self._calls += 1
        self._conn.send((self._calls, name, args))
        while True:
            reply = self._conn.recv()
            value = self._answer(reply)
            if reply[1] == self._calls:
                return value

    @staticmethod
    def _answer(reply):
        kind, _, value = reply
        if kind == 'ok':
            return value
        is_ours, text = value
        if is_ours:
            raise LaserTrackerError(text)
        raise RuntimeError(f'the recording process failed: {text}')


@dataclass
class StepRecord:
    """What :meth:`RunRecorder.step` reads of a ``core.pipeline.StepResult``."""

    scan: object
    ego: object
    stamp: float
    detection: object


def _serve(options: RecordOptions, conn, replay_end) -> None:
    """The recording process: a RunRecorder answering :class:`RecordingProcess`. Replies
    ``(kind, call number, value)``; a failed queued call is said once, unasked (call number
    None), and the calls after it are skipped (their replies are errors). Whenever it ends
    without the replay's ``__exit__`` (the replay died: end of the pipe; SIGTERM), the
    partial recording is removed."""
    import signal

    replay_end.close()        # the replay's end, inherited: else the pipe never ends here
    signal.signal(signal.SIGINT, signal.SIG_IGN)     # Ctrl-C: the replay decides

    def terminated(signum, frame):
        raise SystemExit(143)

    signal.signal(signal.SIGTERM, terminated)
    recorder = RunRecorder(options)
    entered = False
    try:
        entered = _answer_calls(recorder, conn)
    finally:
        if entered:                              # not closed by the replay: nothing is left
            recorder.__exit__(LaserTrackerError, LaserTrackerError('aborted'), None)


def _answer_calls(recorder: RunRecorder, conn) -> bool:
    """:func:`_serve`'s loop; returns whether the recording is still open (the replay is
    gone without closing it)."""
    import traceback

    entered = False
    failure = None
    while True:
        try:
            number, name, args = conn.recv()
        except (EOFError, OSError):            # the replay is gone
            return entered
        if failure is not None and name != '__exit__':
            reply = ('error', number, failure)
        else:
            try:
                if name == '__exit__':
                    entered = False           # closed by this call, whatever it says
                value = getattr(recorder, name)(*args)
                if name == 'start':
                    value = recorder.passthrough_topics
                elif name == '__exit__':
                    value = recorder.summary()        # the recording as written
                elif name == '__enter__':
                    value, entered = None, True
                reply = ('ok', number, value)
            except LaserTrackerError as exc:
                reply = ('error', number, (True, str(exc)))
            except Exception:  # noqa: BLE001 - a bug: its traceback, in the replay
                reply = ('error', number, (False, traceback.format_exc()))
            if reply[0] == 'error':
                failure = failure or reply[2]
                if number is None:               # a queued call: said once, unasked
                    number = -1
        if number is not None:
            try:
                conn.send(reply)
            except OSError:
                return entered
        if name == '__exit__':
            return False


def _stamped(tf_message, ns: int):
    """Every transform of a TFMessage stamped with ``ns`` exactly."""
    stamp = time_msg(FACTORY, ns)
    for t in tf_message.transforms:
        t.header.stamp = stamp
    return tf_message
