"""Recordings: rosbag2 (sqlite3 or mcap) written with rosbags; rosbag2 and ROS 1 bags read.

Topics of a laser_tracker recording (README.md, "Bundled recordings"):
``/scan`` sensor_msgs/LaserScan, ``/odom`` nav_msgs/Odometry, ``/ground_truth``
visualization_msgs/MarkerArray (the moving-object schema of ``laser_tracker.conversions``),
``/ground_truth/platform`` nav_msgs/Odometry (the platform's true pose).
"""
from __future__ import annotations

import functools
import sys
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness, QosReliability,
                                QosTime)
from rosbags.typesys import Stores, get_typestore

from laser_tracker.conversions import (MovingObject, bag_factory, objects_from_marker_array,
                                       odometry_from_msg, scan_from_msg, sec_to_ns)
from laser_tracker.core.scan import Scan, ScanError
from laser_tracker.errors import InputFileError
from laser_tracker.tools.atomic import atomic_path
from laser_tracker.tools.compact_mcap import compact_mcap, zstd

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
FACTORY = bag_factory(TYPESTORE)

SCAN_TOPIC = '/scan'
ODOM_TOPIC = '/odom'
GROUND_TRUTH_TOPIC = '/ground_truth'
PLATFORM_TRUTH_TOPIC = '/ground_truth/platform'
PACKAGE = 'laser_tracker'
TF_STATIC_TOPIC = '/tf_static'

# The QoS tf2's static broadcaster offers: reliable, transient local (latched), keep last 1.
LATCHED_QOS = (Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE,
                   QosDurability.TRANSIENT_LOCAL, QosTime(0, 0), QosTime(0, 0),
                   QosLiveliness.AUTOMATIC, QosTime(0, 0), False),)


#: zstd level of the chunks a compact recording is first written with (rewritten after).
FAST_ZSTD_LEVEL = 1


class BagWriter:
    """Write a rosbag2 recording that appears only when complete.

    ``with BagWriter(path) as bag: bag.write('/scan', msg, stamp)``: the recording is written in
    a temporary sibling folder and moved to ``path`` on success; after an error (in the block,
    or while closing: a full disk) nothing is left. ``compact`` (mcap storage only): once
    written, the file is rewritten in time order, zstd-compressed, without message indexes
    (``tools.compact_mcap``: Foxglove, ``ros2 bag`` and rosbags read it), whatever order the
    messages were written in.
    """

    def __init__(self, path: str | Path, storage: str = 'sqlite3', overwrite: bool = False,
                 compact: bool = False):
        if storage not in ('sqlite3', 'mcap'):
            raise ValueError(f'storage must be sqlite3 or mcap, got {storage!r}')
        self.path, self.storage, self.overwrite = Path(path), storage, overwrite
        self.compact = compact and storage == 'mcap'
        self._connections = {}
        self._atomic = None
        self._tmp: Path | None = None
        self._writer = None

    def __enter__(self) -> BagWriter:
        from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

        self._atomic = atomic_path(self.path, overwrite=self.overwrite)
        self._tmp = tmp = self._atomic.__enter__()
        try:
            plugin = StoragePlugin.MCAP if self.storage == 'mcap' else StoragePlugin.SQLITE3
            self._writer = Writer(tmp, version=8, storage_plugin=plugin)
            if self.compact:
                self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
            self._writer.open()
            if self.compact and hasattr(self._writer.storage, 'compressor'):
                self._writer.storage.compressor = functools.partial(zstd().compress,
                                                                    level=FAST_ZSTD_LEVEL)
        except BaseException as exc:
            self._atomic.__exit__(type(exc), exc, exc.__traceback__)
            raise
        return self

    def write(self, topic: str, msg, stamp: float | int, qos=()) -> None:
        """Append ``msg`` (a rosbags message) on ``topic`` with receive time ``stamp``.

        ``stamp`` is seconds (float) or, to keep a recording's times exactly, integer ns.
        ``qos``: the topic's offered QoS profiles (rosbags ``Qos``), taken from its first
        message (e.g. :data:`LATCHED_QOS` for /tf_static).
        """
        msgtype = msg.__msgtype__
        conn = self._connections.get(topic)
        if conn is None:
            conn = self._writer.add_connection(topic, msgtype, typestore=TYPESTORE,
                                               offered_qos_profiles=list(qos))
            self._connections[topic] = conn
        ns = stamp if isinstance(stamp, int) else sec_to_ns(stamp)
        self._writer.write(conn, ns, TYPESTORE.serialize_cdr(msg, msgtype))

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            try:
                self._writer.close()
                if self.compact:
                    compact_mcap(self._tmp)
            except BaseException as err:       # e.g. the disk filled while closing
                self._abort()
                self._atomic.__exit__(type(err), err, err.__traceback__)
                raise
            self._atomic.__exit__(None, None, None)
        else:
            self._abort()
            self._atomic.__exit__(exc_type, exc, tb)
        return False

    def _abort(self) -> None:
        try:
            self._writer.abort()
        except Exception:  # noqa: BLE001 - the folder is removed regardless
            pass


def open_reader(path: str | Path) -> AnyReader:
    """An open AnyReader of the recording at ``path`` (close it after use).

    InputFileError for anything that is not a readable recording, saying what it is when it
    can tell: a CARMEN log names ``import-carmen``, a rosbag2 metadata file names its folder.
    """
    path = Path(path)
    if not path.exists():
        raise InputFileError(path, 'no such file or folder')
    not_a_bag = _what_else(path)
    if not_a_bag:
        raise InputFileError(path, not_a_bag)
    try:
        reader = AnyReader([path], default_typestore=TYPESTORE)
        reader.open()
    except Exception as exc:  # rosbags raises several unrelated types for damaged files
        raise InputFileError(path, f'not a readable bag: {exc}') from None
    return reader


def _what_else(path: Path) -> str | None:
    """Why ``path`` is not a recording, when that is clear before trying to read it."""
    from laser_tracker.tools.carmen import looks_like_carmen

    recordings = 'a recording is a rosbag2 folder or a ROS 1 .bag file'
    if path.is_dir():
        if (path / 'metadata.yaml').is_file():
            return None
        if (path / 'summary.json').is_file() and (path / 'tracks.csv').is_file():
            return ('a `laser-tracker replay` output, not a recording (its summary.json names '
                    'the recording it replayed)')
        return f'not a rosbag2 folder (no metadata.yaml in it); {recordings}'

    if path.name == 'metadata.yaml':
        return f'give the rosbag2 folder that holds this file: {path.parent}'
    if path.suffix in ('.bag', '.db3', '.mcap'):
        return None
    if looks_like_carmen(path):
        return ('a CARMEN log, not a recording: convert it first with '
                f'`laser-tracker import-carmen {path} OUT`, then use OUT')
    return f'not a recording ({recordings})'


def topics(path: str | Path) -> dict[str, tuple[str, int]]:
    """``{topic: (msgtype, message count)}`` of a recording."""
    reader = open_reader(path)
    try:
        return {c.topic: (c.msgtype, c.msgcount) for c in reader.connections}
    finally:
        reader.close()


def iter_records(reader: AnyReader, path: str | Path, connections, start_ns: int | None = None
                 ) -> Iterator[tuple[object, int, bytes]]:
    """Yield ``(connection, receive time ns, serialized message)`` of ``connections`` of an
    open reader in time order, from ``start_ns`` on; damage raises InputFileError."""
    index = 0
    try:
        for conn, t_ns, raw in reader.messages(connections=connections, start=start_ns):
            index += 1
            yield conn, t_ns, raw
    except Exception as exc:
        raise InputFileError(path, f'damaged recording: {exc}',
                             f'after message {index}') from None


def cdr_converter(reader: AnyReader, msgtype: str) -> Callable[[bytes], bytes] | None:
    """How a record of ``msgtype`` read by ``reader`` becomes ROS 2 CDR of the Jazzy
    definition (what rclpy publishes and ``rclpy.serialization.deserialize_message`` reads):
    as it is when the wire formats agree (a rosbag2 record), converted from ROS 1
    serialization (``std_msgs/Header`` loses ``seq``), or migrated field by field where the
    definitions differ (ROS 1 ``visualization_msgs/Marker``: new fields get their defaults).
    A type Jazzy does not define passes as recorded in a rosbag2 recording; from a ROS 1
    recording it cannot be converted (None)."""
    from rosbags.convert.converter import is_same_wireformat, migrate_bytes

    source = reader.typestore
    if msgtype not in TYPESTORE.fielddefs:
        return bytes if reader.is2 else None
    if is_same_wireformat(source, TYPESTORE, msgtype, msgtype):
        if reader.is2:
            return bytes
        return lambda raw: bytes(TYPESTORE.ros1_to_cdr(raw, msgtype))
    cache: dict = {}
    return lambda raw: bytes(migrate_bytes(source, TYPESTORE, msgtype, msgtype, cache, raw,
                                           src_is2=reader.is2, dst_is2=True))


def recorded_as_latched(connection) -> bool:
    """Whether a recording's topic was latched: transient-local offered QoS (rosbag2) or
    ``latching`` (ROS 1), as tf2's static broadcaster does."""
    from rosbags.interfaces import QosDurability

    ext = connection.ext
    if getattr(ext, 'latching', None):
        return True
    return any(q.durability == QosDurability.TRANSIENT_LOCAL
               for q in getattr(ext, 'offered_qos_profiles', None) or ())


def iter_messages(path: str | Path, topic_names: Iterable[str]) -> Iterator[tuple[str, int, object]]:
    """Yield ``(topic, receive time ns, message)`` in time order for the given topics.

    A message that cannot be deserialised raises InputFileError naming its index and time.
    """
    path = Path(path)
    reader = open_reader(path)
    wanted = set(topic_names)
    try:
        conns = [c for c in reader.connections if c.topic in wanted]
        for index, (conn, t_ns, raw) in enumerate(iter_records(reader, path, conns)):
            try:
                msg = reader.deserialize(raw, conn.msgtype)
            except Exception as exc:
                raise InputFileError(path, f'cannot decode {conn.msgtype}: {exc}',
                                     f'message {index} on {conn.topic} at t={t_ns} ns') \
                    from None
            yield conn.topic, t_ns, msg
    finally:
        reader.close()


def stamp_if_unstamped(msg, receive_ns: int) -> bool:
    """Give a scan or odometry message whose header stamp was never set (0, from a driver
    or simulator that leaves it) its receive time in the recording; True if it did. Every
    such message would otherwise carry the same stamp, and all but the first be skipped."""
    stamp = msg.header.stamp
    if stamp.sec != 0 or stamp.nanosec != 0 or receive_ns <= 0:
        return False
    stamp.sec, stamp.nanosec = divmod(int(receive_ns), 1_000_000_000)
    return True


def read_scans(path: str | Path, topic: str = SCAN_TOPIC) -> Iterator[Scan | ScanError]:
    """Scans of ``topic``; a malformed scan is yielded as its ScanError for the caller to skip.
    A scan without a header stamp gets its receive time (:func:`stamp_if_unstamped`)."""
    for _, t_ns, msg in iter_messages(path, [topic]):
        stamp_if_unstamped(msg, t_ns)
        try:
            yield scan_from_msg(msg)
        except ScanError as exc:
            yield exc


@dataclass
class PoseTrack:
    """Time-stamped planar poses, e.g. odometry: ``stamps`` (N,), ``poses`` (N, 3) x, y, theta."""

    stamps: np.ndarray
    poses: np.ndarray

    def __len__(self) -> int:
        return int(self.stamps.size)


def read_odometry(path: str | Path, topic: str = ODOM_TOPIC) -> PoseTrack:
    """Every Odometry message of ``topic`` as a PoseTrack, in the order recorded (one without
    a header stamp at its receive time)."""
    rows = []
    for _, t_ns, msg in iter_messages(path, [topic]):
        stamp_if_unstamped(msg, t_ns)
        o = odometry_from_msg(msg)
        rows.append((o.stamp, o.x, o.y, o.theta))
    arr = np.array(rows, dtype=float).reshape(-1, 4)
    return PoseTrack(stamps=arr[:, 0].copy(), poses=arr[:, 1:].copy())


@dataclass
class GroundTruthFrame:
    """The moving objects at one instant, positions in ``frame_id`` (the world frame)."""

    stamp: float
    frame_id: str
    objects: list[MovingObject]


def read_ground_truth(path: str | Path, topic: str = GROUND_TRUTH_TOPIC) -> list[GroundTruthFrame]:
    """The ground truth of a simulated recording, one frame per ``/ground_truth`` message.

    Raises InputFileError if the recording has no such topic (e.g. a real recording).
    """
    if topic not in topics(path):
        raise InputFileError(path, f'has no ground truth (no {topic} topic)')
    frames = []
    for _, _, msg in iter_messages(path, [topic]):
        stamp, frame_id, objects = objects_from_marker_array(msg)
        frames.append(GroundTruthFrame(stamp, frame_id, objects))
    return frames


def read_platform_truth(path: str | Path, topic: str = PLATFORM_TRUTH_TOPIC) -> PoseTrack:
    if topic not in topics(path):
        raise InputFileError(path, f'has no platform ground truth (no {topic} topic)')
    return read_odometry(path, topic)


# ------------------------------------------------------------------ bundled recordings


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
    found = topics(bag)
    return GROUND_TRUTH_TOPIC in found and PLATFORM_TRUTH_TOPIC in found


SCAN_MSGTYPE = 'sensor_msgs/msg/LaserScan'
ODOMETRY_MSGTYPE = 'nav_msgs/msg/Odometry'


def absolute_topic(name: str) -> str:
    """A topic name as a recording holds it: a relative name (``scan``) means ``/scan``."""
    return name if name.startswith('/') else '/' + name


def topics_of_type(info: dict[str, tuple[str, int]], msgtype: str) -> list[str]:
    """The topics of ``msgtype`` among a recording's :func:`topics`, by name."""
    return sorted(t for t, (typ, _) in info.items() if typ == msgtype)


def require_topic(path: str | Path, info: dict[str, tuple[str, int]], name: str, msgtype: str,
                  option: str) -> str:
    """``name`` (relative means absolute) as a topic of ``msgtype`` in the recording at
    ``path`` whose :func:`topics` are ``info``. InputFileError naming ``option`` when the
    recording has no such topic or it is of another type, listing its topics of that type."""
    topic = absolute_topic(name)
    kind = msgtype.rsplit('/', 1)[-1]
    have = f'its {kind} topics: {", ".join(topics_of_type(info, msgtype)) or "none"}'
    if topic not in info:
        raise InputFileError(path, f'{option} {name}: no such topic; {have}')
    if info[topic][0] != msgtype:
        raise InputFileError(path, f'{option} {name}: a {info[topic][0]} topic, not '
                             f'{msgtype}; {have}')
    return topic


def scan_topics(path: str | Path) -> list[str]:
    """The sensor_msgs/LaserScan topics of a recording that hold messages, by name."""
    return sorted(t for t, (typ, n) in topics(path).items() if typ == SCAN_MSGTYPE and n)


def scan_topic_of(path: str | Path, name: str | None, option: str = '--scan-topic') -> str:
    """The LaserScan topic ``name`` of a recording, checked as :func:`require_topic` does, or
    its only LaserScan topic when ``name`` is None (InputFileError if it has none or several:
    the error names ``option``)."""
    info = topics(path)
    if name is not None:
        return require_topic(path, info, name, SCAN_MSGTYPE, option)
    found = topics_of_type(info, SCAN_MSGTYPE)
    if len(found) != 1:
        raise InputFileError(path, f'{len(found) or "no"} LaserScan topics'
                             + (f' ({", ".join(found)}): choose one with {option}' if found
                                else f' (it has: {", ".join(sorted(info)) or "nothing"})'))
    return found[0]


@dataclass
class ScanTimes:
    """When each scan of a topic was recorded: ``receive_ns`` (N,) the bag's receive times
    (integer ns, the order of the recording) and ``stamps`` (N,) the header stamps (s), which
    ``laser-tracker replay`` writes; ``frame_id`` of the first scan."""

    topic: str
    receive_ns: np.ndarray
    stamps: np.ndarray
    frame_id: str

    def __len__(self) -> int:
        return int(self.stamps.size)


def read_scan_times(path: str | Path, topic: str = SCAN_TOPIC) -> ScanTimes:
    """Receive times and header stamps of every message on ``topic``, in receive order (the
    receive time for a scan without a header stamp, as the replay stamps it).

    Raises InputFileError when the recording has no such LaserScan topic.
    """
    from laser_tracker.conversions import stamp_to_sec

    topic = require_topic(path, topics(path), topic, SCAN_MSGTYPE, '--scan-topic')
    receive, stamps, frame = [], [], ''
    for _, t_ns, msg in iter_messages(path, [topic]):
        receive.append(int(t_ns))
        stamp_if_unstamped(msg, t_ns)
        stamps.append(stamp_to_sec(msg.header.stamp))
        frame = frame or str(msg.header.frame_id)
    order = np.argsort(np.asarray(receive, np.int64), kind='stable')
    return ScanTimes(topic, np.asarray(receive, np.int64)[order],
                     np.asarray(stamps, float)[order], frame)
