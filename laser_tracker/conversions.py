"""Message conversion in one place, for rclpy messages and rosbags messages alike.

Reading works on either kind by attribute names (both follow the same .msg definitions).
Writing goes through a :class:`MessageFactory`: :func:`ros_factory` builds rclpy messages,
:func:`bag_factory` rosbags messages for a typestore (it fills every field a builder leaves
out with its default, because rosbags classes have no defaults).

The moving-object schema (``visualization_msgs/MarkerArray``), shared by ``/ground_truth``
and the tracker's ``tracks`` topic, is documented in README.md ("Topics and schemas"):

* the array starts with one ``DELETEALL`` marker (so a viewer drops objects that vanished);
* then one ``ARROW`` marker per object: ``id`` = object / track id, ``ns`` = the stream
  (``ground_truth``, ``tracks``, ...), ``header.frame_id`` = the frame of the positions;
  ``pose.position`` = the object's centre (x, y; z = 0), ``pose.orientation`` = identity;
  ``points = [(0, 0, 0), (vx, vy, 0)]`` relative to the pose, i.e. the velocity in m/s
  (RViz draws an arrow covering one second of travel);
  ``text`` = a JSON object with the extra fields (``kind``, ``visible``, ``beams`` for ground
  truth; ``weight``, ``confirmed``, ``samples``, ``kind``, ``moving``, ``covariance`` for
  tracks: :func:`tracks_to_objects`).
"""
from __future__ import annotations

import array
import functools
import importlib
import json
import math
import struct
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from laser_tracker.core.scan import Scan, ScanError

# ----------------------------------------------------------------------------------- time


def stamp_to_sec(stamp) -> float:
    """builtin_interfaces/Time (or Duration) -> seconds."""
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


def sec_to_sec_nanosec(t: float) -> tuple[int, int]:
    """Seconds -> (sec, nanosec) with 0 <= nanosec < 1e9; negative times are refused."""
    if not math.isfinite(t) or t < 0:
        raise ValueError(f'time stamp must be finite and non-negative, got {t!r}')
    ns = int(round(t * 1e9))
    return ns // 1_000_000_000, ns % 1_000_000_000


def sec_to_ns(t: float) -> int:
    sec, nsec = sec_to_sec_nanosec(t)
    return sec * 1_000_000_000 + nsec


def stamp_to_ns(stamp) -> int:
    """builtin_interfaces/Time -> integer nanoseconds, exactly.

    Use it to compare or pair stamps: seconds as a float have only ~0.24 us resolution at
    today's epoch times, so a float round trip does not give back the same stamp.
    """
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def time_msg(factory: MessageFactory, ns: int):
    """builtin_interfaces/Time of integer nanoseconds, exactly."""
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    return factory.make('builtin_interfaces/msg/Time', sec=sec, nanosec=nanosec)


def restamp(msg, stamp):
    """Set the exact header stamp (a Time message) on ``msg``, or on every marker of a
    MarkerArray, so outputs carry their input's stamp bit for bit. Returns ``msg``."""
    for item in getattr(msg, 'markers', None) or [msg]:
        item.header.stamp = stamp
    return msg


def restamp_ns(factory: MessageFactory, msg, ns: int | None):
    """:func:`restamp` with the exact stamp in integer nanoseconds (None: leave as is)."""
    return msg if ns is None else restamp(msg, time_msg(factory, ns))


# ----------------------------------------------------------------------------- orientation


def yaw_from_quaternion(q) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def quaternion_from_yaw(yaw: float) -> dict[str, float]:
    return {'x': 0.0, 'y': 0.0, 'z': math.sin(yaw / 2.0), 'w': math.cos(yaw / 2.0)}


# -------------------------------------------------------------------------------- factory


class MessageFactory:
    """Builds messages of one library; ``make('pkg/msg/Type', **fields)``."""

    def make(self, type_name: str, **fields):  # pragma: no cover - interface
        raise NotImplementedError

    def float32_array(self, values) -> Any:  # pragma: no cover - interface
        raise NotImplementedError

    def float64_array(self, values) -> Any:  # pragma: no cover - interface
        raise NotImplementedError

    def int8_array(self, values) -> Any:  # pragma: no cover - interface
        raise NotImplementedError

    def byte(self, value: int) -> Any:
        """A ``byte`` field's value (rclpy wants a 1-byte ``bytes``, rosbags an int)."""
        return bytes([int(value)])


class _RosFactory(MessageFactory):
    def __init__(self):
        self._classes: dict[str, type] = {}

    def message_class(self, type_name: str):
        """The rclpy class of ``pkg/msg/Type`` (ImportError / AttributeError if absent)."""
        cls = self._classes.get(type_name)
        if cls is None:
            pkg, _, name = type_name.split('/')
            cls = getattr(importlib.import_module(f'{pkg}.msg'), name)
            self._classes[type_name] = cls
        return cls

    def make(self, type_name: str, **fields):
        return self.message_class(type_name)(**fields)

    def float32_array(self, values):
        out = array.array('f')
        out.frombytes(np.ascontiguousarray(values, dtype=np.float32).tobytes())
        return out

    def float64_array(self, values):
        return [float(v) for v in np.asarray(values, dtype=np.float64).reshape(-1)]

    def int8_array(self, values):
        out = array.array('b')
        out.frombytes(np.ascontiguousarray(values, dtype=np.int8).tobytes())
        return out


class _BagFactory(MessageFactory):
    def __init__(self, typestore):
        self.typestore = typestore
        self._plans: dict[str, tuple] = {}    # type -> (class, [(field, default maker)])
        self._rounding: dict[str, Any] = {}   # type -> how its float64 fields are stored

    def _plan(self, type_name: str) -> tuple:
        plan = self._plans.get(type_name)
        if plan is None:
            _, fielddefs = self.typestore.fielddefs[type_name]
            plan = self._plans[type_name] = (self.typestore.types[type_name],
                                             [(f, self._maker(d)) for f, d in fielddefs])
        return plan

    def _maker(self, desc):
        """A function returning a fresh default value for a field of description ``desc``."""
        nodetype, detail = desc
        kind = int(nodetype)
        if kind == 1:  # BASE: immutable values
            base = detail[0]
            value = '' if base == 'string' else False if base == 'bool' else \
                0.0 if base.startswith('float') else 0
            return lambda: value
        if kind == 2:  # NAME: a message of defaults, built without make's checks
            def default():
                cls, plan = self._plan(detail)
                return cls(**{name: field_default() for name, field_default in plan})
            return default
        inner, count = detail
        if int(inner[0]) == 1 and inner[1][0] != 'string':
            dtype = _numpy_dtype(inner[1][0])
            size = count if kind == 3 else 0      # fixed ARRAY or SEQUENCE
            return lambda: np.zeros(size, dtype=dtype)
        if kind == 3:
            element = self._maker(inner)
            return lambda: [element() for _ in range(count)]
        return list

    def make(self, type_name: str, **fields):
        cls, plan = self._plans.get(type_name) or self._plan(type_name)
        rounding = self._rounding.get(type_name)
        if rounding is not None:                # every field is a float64
            for fname, value in fields.items():
                fields[fname] = rounding(value)
        for fname, default in plan:
            if fname not in fields:
                fields[fname] = default()
        return cls(**fields)

    def float32_array(self, values):
        return np.ascontiguousarray(values, dtype=np.float32)

    def float64_array(self, values):
        return np.ascontiguousarray(values, dtype=np.float64).reshape(-1)

    def int8_array(self, values):
        return np.ascontiguousarray(values, dtype=np.int8).reshape(-1)

    def byte(self, value: int) -> Any:
        return int(value)


class _RecordingFactory(_BagFactory):
    """:func:`recording_factory`'s."""

    def __init__(self, typestore, position_step: float):
        super().__init__(typestore)
        on_grid = functools.partial(_on_grid, float(position_step))
        self._rounding = {'geometry_msgs/msg/Point': on_grid,
                          'geometry_msgs/msg/Vector3': on_grid,
                          'geometry_msgs/msg/Quaternion': _float32}

    def _maker(self, desc):
        if int(desc[0]) != 2 or desc[1] == 'std_msgs/msg/Header':   # restamp() changes those
            return super()._maker(desc)
        fresh, shared = super()._maker(desc), []

        def default():                  # one message of defaults for all who leave it out
            if not shared:
                shared.append(fresh())
            return shared[0]
        return default

    def float64_array(self, values):
        return _significant_bits(super().float64_array(values), 10)


def _on_grid(step: float, value: float) -> float:
    """``value`` rounded to a multiple of ``step`` (as it is when not finite)."""
    try:
        return round(value / step) * step
    except (OverflowError, ValueError):
        return value


def _significant_bits(values: np.ndarray, bits: int) -> np.ndarray:
    """``values`` (float64) rounded to ``bits`` bits after the leading one (10: about 3
    significant digits); values beyond float32's range as they are."""
    with np.errstate(over='ignore'):
        single = values.astype(np.float32)
    dropped = 23 - bits
    mantissa = (single.view(np.uint32) + np.uint32(1 << (dropped - 1))) \
        & np.uint32(0xFFFFFFFF ^ ((1 << dropped) - 1))
    rounded = mantissa.view(np.float32).astype(np.float64)
    return np.where(np.isfinite(single) & np.isfinite(rounded), rounded, values)


def _float32(value: float) -> float:
    """``value`` at float32 precision (as it is when too large for a float32)."""
    try:
        return struct.unpack('<f', struct.pack('<f', value))[0]
    except OverflowError:
        return value


def _numpy_dtype(base: str):
    """numpy dtype of a ROS primitive array element (byte, char and octet are uint8)."""
    return np.uint8 if base in ('byte', 'char', 'octet') else np.dtype(base)


_ROS_FACTORY: _RosFactory | None = None


def ros_factory() -> MessageFactory:
    """rclpy message classes (imported on first use)."""
    global _ROS_FACTORY
    if _ROS_FACTORY is None:
        _ROS_FACTORY = _RosFactory()
    return _ROS_FACTORY


def bag_factory(typestore) -> MessageFactory:
    """rosbags message classes of ``typestore``."""
    return _BagFactory(typestore)


def recording_factory(typestore, position_step: float) -> MessageFactory:
    """rosbags message classes of ``typestore`` for messages written once and dropped (a
    recording of a run): built as a recording stores them, and quickly.

    Positions and vectors (geometry_msgs Point, Vector3: m, m/s, rad/s) are rounded to a
    multiple of ``position_step`` (e.g. 1/1024 m: about 1 mm), orientations (Quaternion) to
    float32 precision (7 significant digits) and float64 arrays (covariances) to 3
    significant digits: values with few significant bits take 2-4 bytes of a compressed
    recording instead of 8. A sub-message left out (a Marker's texture, mesh, lifetime, a
    DELETEALL's pose; not a header) is one message of defaults shared by all: nothing may
    change it."""
    return _RecordingFactory(typestore, position_step)


def header(factory: MessageFactory, stamp: float, frame_id: str):
    sec, nanosec = sec_to_sec_nanosec(stamp)
    return factory.make('std_msgs/msg/Header',
                        stamp=factory.make('builtin_interfaces/msg/Time', sec=sec,
                                           nanosec=nanosec),
                        frame_id=frame_id)


# ----------------------------------------------------------------------------- LaserScan


def scan_from_msg(msg) -> Scan:
    """sensor_msgs/LaserScan -> Scan. Raises ScanError for a scan that cannot be used."""
    ranges = np.asarray(msg.ranges, dtype=np.float64)
    inc = float(msg.angle_increment)
    if ranges.size > 1 and np.isfinite(inc) and inc != 0.0:
        # angle_max is redundant; a mismatch means a malformed message.
        expected = int(round((float(msg.angle_max) - float(msg.angle_min)) / inc)) + 1
        if abs(expected - ranges.size) > 1:
            raise ScanError(f'{ranges.size} ranges but angle_min/angle_max/angle_increment '
                            f'describe {expected} beams')
    return Scan(stamp=stamp_to_sec(msg.header.stamp), ranges=ranges,
                angle_min=float(msg.angle_min), angle_increment=inc,
                range_min=float(msg.range_min), range_max=float(msg.range_max),
                time_increment=float(msg.time_increment), scan_time=float(msg.scan_time),
                frame_id=str(msg.header.frame_id), stamp_ns=stamp_to_ns(msg.header.stamp))


def scan_to_msg(factory: MessageFactory, scan: Scan, intensities=None):
    n = scan.n_beams
    return factory.make(
        'sensor_msgs/msg/LaserScan',
        header=header(factory, scan.stamp, scan.frame_id),
        angle_min=float(scan.angle_min),
        angle_max=float(scan.angle_min + scan.angle_increment * (n - 1)),
        angle_increment=float(scan.angle_increment),
        time_increment=float(scan.time_increment),
        scan_time=float(scan.scan_time),
        range_min=float(scan.range_min),
        range_max=float(scan.range_max),
        ranges=factory.float32_array(scan.ranges),
        intensities=factory.float32_array(np.zeros(0) if intensities is None else intensities),
    )


# ------------------------------------------------------------------------------ Odometry


@dataclass
class PlanarOdometry:
    """The planar content of a nav_msgs/Odometry message."""

    stamp: float
    x: float
    y: float
    theta: float
    vx: float = 0.0
    vy: float = 0.0
    omega: float = 0.0
    frame_id: str = 'odom'
    child_frame_id: str = 'base_link'

    @property
    def pose(self) -> np.ndarray:
        return np.array([self.x, self.y, self.theta])


def odometry_from_msg(msg) -> PlanarOdometry:
    p = msg.pose.pose
    tw = msg.twist.twist
    return PlanarOdometry(stamp=stamp_to_sec(msg.header.stamp), x=float(p.position.x),
                          y=float(p.position.y), theta=yaw_from_quaternion(p.orientation),
                          vx=float(tw.linear.x), vy=float(tw.linear.y),
                          omega=float(tw.angular.z), frame_id=str(msg.header.frame_id),
                          child_frame_id=str(msg.child_frame_id))


#: Where the terms of a planar (x, y, yaw) 3 x 3 covariance go in a flat 6 x 6 one.
_PLANAR_IN_6X6 = (6 * np.array([0, 1, 5])[:, None] + np.array([0, 1, 5])).reshape(-1)


def _covariance(factory: MessageFactory, cov) -> Any:
    """A 6 x 6 covariance (x, y, z, roll, pitch, yaw) as the message wants it, from the 6
    diagonal terms, a planar 3 x 3 (x, y, yaw) covariance, or None (zeros)."""
    out = np.zeros(36)
    if cov is not None:
        cov = np.asarray(cov, dtype=float)
        if cov.shape == (3, 3):
            out[_PLANAR_IN_6X6] = cov.reshape(9)
        else:
            out[::7] = cov.reshape(6)
    return factory.float64_array(out)


def planar_covariance(cov36) -> np.ndarray:
    """The x, y, yaw block (3 x 3) of a 6 x 6 message covariance; ValueError if it is not 36
    numbers."""
    cov = np.asarray(cov36, dtype=float).ravel()
    if cov.size != 36:
        raise ValueError(f'covariance has {cov.size} terms, not 36')
    idx = np.array([0, 1, 5])
    return cov.reshape(6, 6)[np.ix_(idx, idx)].copy()


def odometry_to_msg(factory: MessageFactory, odom: PlanarOdometry, pose_variance=None,
                    twist_variance=None):
    """PlanarOdometry -> nav_msgs/Odometry; covariances as 6 diagonal terms, a planar 3 x 3
    (x, y, yaw) matrix, or None."""
    f = factory
    pose = f.make('geometry_msgs/msg/Pose',
                  position=f.make('geometry_msgs/msg/Point', x=float(odom.x), y=float(odom.y),
                                  z=0.0),
                  orientation=f.make('geometry_msgs/msg/Quaternion',
                                     **quaternion_from_yaw(float(odom.theta))))
    twist = f.make('geometry_msgs/msg/Twist',
                   linear=f.make('geometry_msgs/msg/Vector3', x=float(odom.vx),
                                 y=float(odom.vy), z=0.0),
                   angular=f.make('geometry_msgs/msg/Vector3', x=0.0, y=0.0,
                                  z=float(odom.omega)))
    return f.make('nav_msgs/msg/Odometry',
                  header=header(f, odom.stamp, odom.frame_id),
                  child_frame_id=odom.child_frame_id,
                  pose=f.make('geometry_msgs/msg/PoseWithCovariance', pose=pose,
                              covariance=_covariance(f, pose_variance)),
                  twist=f.make('geometry_msgs/msg/TwistWithCovariance', twist=twist,
                               covariance=_covariance(f, twist_variance)))


# ------------------------------------------------------------------------------ ego-motion

#: Name of the one DiagnosticStatus in each ``ego_motion/status`` message.
EGO_STATUS_NAME = 'ego_motion'


def ego_motion_to_msgs(factory: MessageFactory, pose):
    """``core.stages.StampedPose`` -> (nav_msgs/Odometry, diagnostic_msgs/DiagnosticArray).

    The Odometry means what Odometry means everywhere: the scanner pose in the odometry frame
    (child frame = the scan's frame) with its covariance (accumulated since the pose chain
    started), and the twist (the motion since the previous scan over its duration, in the
    scanner frame) with its covariance. The DiagnosticArray (``ego_motion/status``, same
    stamp) carries what the detection gate reads: ``source`` (icp, icp_partial, odometry,
    constant_velocity, init), ``motion_variance`` (x, y, yaw variances of that motion; 1e6 each
    when the scan match was refused), ``unmatched`` (fraction of the scan's points the match
    left unexplained), ``restarted`` (the pose chain restarted here: odometry-frame history is
    void), ``trusted`` (for people reading it: whether the default gate trusts it),
    ``reason``, ``self_mask`` (the robot's own body in this scan, :func:`encode_body`),
    ``mirrored`` (the pose is that of the scan turned over: the scanner hangs upside down) and
    ``range_noise`` (m, the scanner's range noise near the robot; '' before it is measured).
    """
    from laser_tracker.core.difference import DifferenceConfig, pose_trusted

    x, y, theta = (float(v) for v in pose.pose)
    dt = float(pose.dt)
    motion = np.asarray(pose.motion, dtype=float)
    twist = np.zeros(3)
    twist_cov = None
    if dt > 0 and np.isfinite(motion).all():
        c, s_ = math.cos(motion[2]), math.sin(motion[2])
        twist = np.array([c * motion[0] + s_ * motion[1], -s_ * motion[0] + c * motion[1],
                          motion[2]]) / dt
        mc = np.asarray(pose.motion_covariance, dtype=float)
        twist_cov = mc / (dt * dt) if np.isfinite(mc).all() else None
    odom = PlanarOdometry(stamp=pose.stamp, x=x, y=y, theta=theta, vx=float(twist[0]),
                          vy=float(twist[1]), omega=float(twist[2]), frame_id=pose.frame_id,
                          child_frame_id=pose.child_frame_id)
    odometry = odometry_to_msg(factory, odom, pose.pose_covariance, twist_cov)
    q = pose.quality
    trusted = pose_trusted(q, DifferenceConfig())
    values = {'source': pose.source,
              'motion_variance': ' '.join(repr(float(v)) for v in q.variance),
              'unmatched': repr(float(q.unmatched)),
              'restarted': 'true' if q.restarted else 'false',
              'trusted': 'true' if trusted else 'false',
              'reason': str(pose.reason)[:200],
              'self_mask': encode_body(pose.body),
              'mirrored': 'true' if pose.mirrored else 'false',
              'range_noise': '' if pose.range_noise is None else f'{pose.range_noise:.4f}'}
    f = factory
    status = f.make('diagnostic_msgs/msg/DiagnosticStatus', level=f.byte(0 if trusted else 1),
                    name=EGO_STATUS_NAME, message=f'{pose.source}: {pose.reason}'[:200],
                    hardware_id='',
                    values=[f.make('diagnostic_msgs/msg/KeyValue', key=k, value=v)
                            for k, v in values.items()])
    array = f.make('diagnostic_msgs/msg/DiagnosticArray',
                   header=header(f, pose.stamp, pose.frame_id), status=[status])
    stamp_ns = pose.stamp_ns
    return restamp_ns(f, odometry, stamp_ns), restamp_ns(f, array, stamp_ns)


def ego_motion_from_msgs(odometry_msg, status_msg=None):
    """Inverse of :func:`ego_motion_to_msgs` (``status_msg`` None: a pose from another
    publisher, trusted, not restarted). ValueError for a message that cannot be read."""
    from laser_tracker.core.difference import FAILED_VARIANCE, PoseQuality
    from laser_tracker.core.stages import StampedPose

    odo = odometry_from_msg(odometry_msg)
    pose = odo.pose
    if not (np.isfinite(pose).all() and math.isfinite(odo.stamp)):
        raise ValueError('ego-motion pose is not finite')
    pose_cov = planar_covariance(odometry_msg.pose.covariance)
    quality, source, reason = PoseQuality(), '', ''
    if status_msg is not None:
        status = next((st for st in status_msg.status if st.name == EGO_STATUS_NAME), None)
        if status is None:
            raise ValueError(f'ego-motion status has no {EGO_STATUS_NAME!r} entry')
        values = {kv.key: kv.value for kv in status.values}
        try:
            variance = tuple(float(v) for v in values['motion_variance'].split())
            unmatched = float(values['unmatched'])
            restarted = values['restarted'] == 'true'
        except (KeyError, ValueError) as exc:
            raise ValueError(f'ego-motion status unreadable: {exc}') from None
        if len(variance) != 3:
            raise ValueError('ego-motion status: motion_variance needs 3 numbers')
        variance = tuple(v if (math.isfinite(v) and v >= 0.0) else FAILED_VARIANCE
                         for v in variance)
        unmatched = unmatched if 0.0 <= unmatched <= 1.0 else 1.0
        quality = PoseQuality(variance, unmatched, restarted)
        source, reason = values.get('source', ''), values.get('reason', '')
        body = decode_body(values.get('self_mask', ''))
        mirrored = values.get('mirrored', 'false') == 'true'
        try:
            range_noise = float(values['range_noise']) if values.get('range_noise') else None
        except ValueError:
            raise ValueError('ego-motion status: range_noise is not a number') from None
    else:
        body, mirrored, range_noise = None, False, None
    return StampedPose(stamp=odo.stamp, pose=pose, motion=np.zeros(3),
                       motion_covariance=np.zeros((3, 3)), pose_covariance=pose_cov,
                       quality=quality, source=source, reason=reason,
                       frame_id=odo.frame_id or 'odom', child_frame_id=odo.child_frame_id,
                       stamp_ns=stamp_to_ns(odometry_msg.header.stamp), body=body,
                       mirrored=mirrored, range_noise=range_noise)


def encode_body(body) -> str:
    """Per-beam body ranges (NaN: none) as text: ``BEAMS|FIRST:R R ...;FIRST:R ...`` with
    each run of masked beams from its first beam index, ranges in whole millimetres rounded
    up ('' when nothing is masked)."""
    if body is None:
        return ''
    body = np.asarray(body, dtype=float)
    masked = np.isfinite(body)
    if not masked.any():
        return ''
    edges = np.flatnonzero(np.diff(np.concatenate(([0], masked.astype(np.int8), [0]))))
    runs = []
    for first, end in zip(edges[::2], edges[1::2]):
        mm = np.ceil(body[first:end] * 1000.0).astype(np.int64)
        runs.append(f'{first}:' + ' '.join(map(str, mm)))
    return f'{body.size}|' + ';'.join(runs)


def decode_body(text: str):
    """Inverse of :func:`encode_body` (None for ''); ValueError when unreadable."""
    if not text:
        return None
    try:
        size, _, runs = text.partition('|')
        body = np.full(int(size), np.nan)
        for run in runs.split(';'):
            first, _, values = run.partition(':')
            mm = np.array(values.split(), dtype=float)
            start = int(first)
            if start < 0 or start + mm.size > body.size:
                raise ValueError(f'run {run[:20]!r} outside {body.size} beams')
            body[start:start + mm.size] = mm / 1000.0
    except (TypeError, ValueError) as exc:
        raise ValueError(f'ego-motion status: self_mask unreadable: {exc}') from None
    return body


# ------------------------------------------------------------------------------- transforms


@dataclass
class PlanarTransform:
    """The planar content of a geometry_msgs/TransformStamped: frame ``child``'s pose
    ``(x, y, yaw)`` in frame ``parent`` (a sensor mount: base_link -> laser); ``tilt``: the
    angle (rad) between the two frames' z axes, which the planar pose leaves out (0: level;
    pi: the child upside down, its scans mirrored)."""

    stamp: float
    parent: str
    child: str
    x: float
    y: float
    yaw: float
    tilt: float = 0.0


def transforms_from_msg(msg) -> list[PlanarTransform]:
    """tf2_msgs/TFMessage (ROS 1 or 2) -> its transforms, planar part; frame names without a
    leading slash (ROS 1 style ``/base_link`` is ``base_link``)."""
    out = []
    for t in msg.transforms:
        tr = t.transform
        out.append(PlanarTransform(stamp=stamp_to_sec(t.header.stamp),
                                   parent=str(t.header.frame_id).lstrip('/'),
                                   child=str(t.child_frame_id).lstrip('/'),
                                   x=float(tr.translation.x), y=float(tr.translation.y),
                                   yaw=yaw_from_quaternion(tr.rotation),
                                   tilt=tilt_from_quaternion(tr.rotation)))
    return out


def tilt_from_quaternion(q) -> float:
    """The angle (rad) between a rotated frame's z axis and the unrotated one's."""
    norm = q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w
    if not norm > 0.0:
        return 0.0
    return math.acos(min(max(1.0 - 2.0 * (q.x * q.x + q.y * q.y) / norm, -1.0), 1.0))


def transforms_to_msg(factory: MessageFactory, transforms) -> Any:
    """PlanarTransforms -> tf2_msgs/TFMessage (what /tf and /tf_static carry)."""
    f = factory
    return f.make('tf2_msgs/msg/TFMessage', transforms=[
        f.make('geometry_msgs/msg/TransformStamped', header=header(f, t.stamp, t.parent),
               child_frame_id=t.child,
               transform=f.make('geometry_msgs/msg/Transform',
                                translation=f.make('geometry_msgs/msg/Vector3', x=float(t.x),
                                                   y=float(t.y), z=0.0),
                                rotation=f.make('geometry_msgs/msg/Quaternion',
                                                **quaternion_from_yaw(float(t.yaw)))))
        for t in transforms])


def tf_message_to_msg(factory: MessageFactory, msg):
    """A tf2_msgs/TFMessage (e.g. read from a ROS 1 bag) rebuilt with ``factory``'s types,
    everything kept (3D translation and rotation, stamps, frame names)."""
    f = factory
    transforms = []
    for t in msg.transforms:
        tr, rot = t.transform.translation, t.transform.rotation
        transforms.append(f.make(
            'geometry_msgs/msg/TransformStamped',
            header=f.make('std_msgs/msg/Header', frame_id=str(t.header.frame_id),
                          stamp=f.make('builtin_interfaces/msg/Time', sec=int(t.header.stamp.sec),
                                       nanosec=int(t.header.stamp.nanosec))),
            child_frame_id=str(t.child_frame_id),
            transform=f.make('geometry_msgs/msg/Transform',
                             translation=f.make('geometry_msgs/msg/Vector3', x=float(tr.x),
                                                y=float(tr.y), z=float(tr.z)),
                             rotation=f.make('geometry_msgs/msg/Quaternion', x=float(rot.x),
                                             y=float(rot.y), z=float(rot.z),
                                             w=float(rot.w)))))
    return f.make('tf2_msgs/msg/TFMessage', transforms=transforms)


# ------------------------------------------------------------------------ moving objects


@dataclass
class MovingObject:
    """One entry of the moving-object MarkerArray schema (ground truth or a track)."""

    id: int
    x: float
    y: float
    vx: float = 0.0
    vy: float = 0.0
    extra: dict = field(default_factory=dict)


MARKER_ARROW = 0
MARKER_ADD = 0
MARKER_DELETEALL = 3


def objects_to_marker_array(factory: MessageFactory, objects, stamp: float, frame_id: str,
                            ns: str, color=(0.1, 0.6, 1.0, 0.9)):
    f = factory
    hdr = header(f, stamp, frame_id)
    markers = [f.make('visualization_msgs/msg/Marker', header=hdr, ns=ns, id=0,
                      action=MARKER_DELETEALL)]
    for obj in objects:
        markers.append(f.make(
            'visualization_msgs/msg/Marker', header=header(f, stamp, frame_id), ns=ns,
            id=int(obj.id), type=MARKER_ARROW, action=MARKER_ADD,
            pose=f.make('geometry_msgs/msg/Pose',
                        position=f.make('geometry_msgs/msg/Point', x=float(obj.x),
                                        y=float(obj.y), z=0.0),
                        orientation=f.make('geometry_msgs/msg/Quaternion', x=0.0, y=0.0,
                                           z=0.0, w=1.0)),
            scale=f.make('geometry_msgs/msg/Vector3', x=0.05, y=0.1, z=0.1),
            color=f.make('std_msgs/msg/ColorRGBA', r=float(color[0]), g=float(color[1]),
                         b=float(color[2]), a=float(color[3])),
            points=[f.make('geometry_msgs/msg/Point', x=0.0, y=0.0, z=0.0),
                    f.make('geometry_msgs/msg/Point', x=float(obj.vx), y=float(obj.vy),
                           z=0.0)],
            text=json.dumps(obj.extra, separators=(',', ':')),
        ))
    return f.make('visualization_msgs/msg/MarkerArray', markers=markers)


def objects_from_marker_array(msg, ns: str | None = None) -> tuple[float, str, list[MovingObject]]:
    """MarkerArray in the moving-object schema -> (stamp, frame_id, objects).

    Markers that are not ADD arrows (or not of ``ns`` when given) are ignored. The stamp and
    frame are those of the first marker (nan and '' for an empty array).
    """
    stamp, frame_id, objects = math.nan, '', []
    for marker in msg.markers:
        if math.isnan(stamp):
            stamp, frame_id = stamp_to_sec(marker.header.stamp), str(marker.header.frame_id)
        if marker.action != MARKER_ADD or marker.type != MARKER_ARROW:
            continue
        if ns is not None and marker.ns != ns:
            continue
        pts = list(marker.points)
        vx = vy = 0.0
        if len(pts) >= 2:
            vx, vy = pts[1].x - pts[0].x, pts[1].y - pts[0].y
        try:
            extra = json.loads(marker.text) if marker.text else {}
        except json.JSONDecodeError:
            extra = {'text': marker.text}
        if not isinstance(extra, dict):
            extra = {'text': marker.text}
        objects.append(MovingObject(id=int(marker.id), x=float(marker.pose.position.x),
                                    y=float(marker.pose.position.y), vx=float(vx),
                                    vy=float(vy), extra=extra))
    return stamp, frame_id, objects


def number(extra: dict, key: str, default: float = 0.0) -> float:
    """A finite number from a decoded JSON ``extra`` (``default`` when absent); ValueError
    naming the key when it is there but not a finite number (another publisher's marker)."""
    value = extra.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value):
        raise ValueError(f'{key} is not a finite number: {value!r}')
    return float(value)


# ---------------------------------------------------------------------------- active head


def joint_state_msg(factory: MessageFactory, stamp: float, names, positions, velocities=()):
    """sensor_msgs/JointState with the given joint names and positions (rad)."""
    f = factory
    return f.make('sensor_msgs/msg/JointState', header=header(f, stamp, ''),
                  name=list(names), position=f.float64_array(positions),
                  velocity=f.float64_array(velocities), effort=f.float64_array(()))


def point_stamped_msg(factory: MessageFactory, stamp: float, frame_id: str, x: float, y: float,
                      z: float = 0.0):
    f = factory
    return f.make('geometry_msgs/msg/PointStamped', header=header(f, stamp, frame_id),
                  point=f.make('geometry_msgs/msg/Point', x=float(x), y=float(y), z=float(z)))


# ------------------------------------------------------------------------------------ blobs

MARKER_CYLINDER = 3
MARKER_POINTS = 8


def detections_to_marker_array(factory: MessageFactory, detections):
    """``core.detections.Detections`` -> the ``blobs`` topic MarkerArray (schema in
    README.md).

    A DELETEALL marker, one CYLINDER per motion blob (ns ``blobs``, id = index, position =
    centroid, scale.x = scale.y = extent, text = JSON ``{"cells": n, "structure": angle or
    null}``), one CYLINDER per person detection (ns ``persons``, id = index, text = JSON
    ``{"confidence": c, "free": bool, "static": bool, "spread": m or null}``: free = where
    the legs stand was seen free before, static = the legs stand on static background,
    spread = the distance between its two legs),
    one POINTS marker (ns ``segments``, id 0) whose points are the scan's compact segments
    (text = JSON ``{"leg": [leg probability of each], "occupied": [s of each]}``; occupied:
    how long the scans have seen its place occupied, absent when not known), one POINTS
    marker (ns ``view``,
    id 0) whose pose is the scanner pose and whose points, one per beam in the scanner's
    frame, are what each beam saw (a return at its end point, z = 0, or z = 0.5 where it lies
    on static background; no return: the point 1 m along the beam, z = 1; too close to
    measure: the same, z = -1), and one ARROW (ns
    ``scanner``, id 0) whose pose is the scanner pose and whose text is JSON
    ``{"restarted": bool}`` (the ego-motion restarted its pose chain: tracks are void).
    """
    f = factory
    stamp, frame_id = float(detections.stamp), detections.frame_id
    blobs, people = detections.blobs, detections.people

    def pose(x, y, yaw=0.0):
        return f.make('geometry_msgs/msg/Pose',
                      position=f.make('geometry_msgs/msg/Point', x=float(x), y=float(y), z=0.0),
                      orientation=f.make('geometry_msgs/msg/Quaternion',
                                         **quaternion_from_yaw(float(yaw))))

    def color(r, g, b, a):
        return f.make('std_msgs/msg/ColorRGBA', r=r, g=g, b=b, a=a)

    markers = [f.make('visualization_msgs/msg/Marker', header=header(f, stamp, frame_id),
                      ns='blobs', id=0, action=MARKER_DELETEALL)]
    for i in range(blobs.count):
        extent = max(float(blobs.extent[i]), 0.05)
        structure = float(blobs.structure[i])
        text = json.dumps({'cells': int(blobs.cells[i]),
                           'structure': None if math.isnan(structure) else structure},
                          separators=(',', ':'))
        markers.append(f.make(
            'visualization_msgs/msg/Marker', header=header(f, stamp, frame_id), ns='blobs',
            id=i, type=MARKER_CYLINDER, action=MARKER_ADD, pose=pose(*blobs.xy[i]),
            scale=f.make('geometry_msgs/msg/Vector3', x=extent, y=extent, z=0.1),
            color=color(1.0, 0.4, 0.0, 0.8), text=text))
    for i, (px, py) in enumerate(np.asarray(people.xy, float).reshape(-1, 2)):
        free = people.free[i] if i < len(people.free) else False
        spread = float(people.spread[i]) if i < len(people.spread) else math.nan
        static = people.static[i] if i < len(people.static) else False
        text = json.dumps({'confidence': round(float(people.confidence[i]), 4),
                           'free': bool(free), 'static': bool(static),
                           'spread': round(spread, 4) if math.isfinite(spread) else None},
                          separators=(',', ':'))
        markers.append(f.make(
            'visualization_msgs/msg/Marker', header=header(f, stamp, frame_id), ns='persons',
            id=i, type=MARKER_CYLINDER, action=MARKER_ADD, pose=pose(px, py),
            scale=f.make('geometry_msgs/msg/Vector3', x=0.5, y=0.5, z=1.0),
            color=color(0.9, 0.1, 0.9, 0.6), text=text))
    segments = np.asarray(detections.segments.xy, float).reshape(-1, 2)
    if segments.shape[0]:
        leg = np.asarray(detections.segments.leg, float).reshape(-1)
        leg = leg if leg.shape[0] == segments.shape[0] else np.zeros(segments.shape[0])
        text = {'leg': [round(float(v), 3) for v in leg]}
        occupied = np.asarray(detections.segments.occupied, float).reshape(-1)
        if occupied.shape[0] == segments.shape[0]:
            text['occupied'] = [round(float(v), 3) for v in occupied]
        markers.append(f.make(
            'visualization_msgs/msg/Marker', header=header(f, stamp, frame_id),
            ns='segments', id=0, type=MARKER_POINTS, action=MARKER_ADD, pose=pose(0.0, 0.0),
            text=json.dumps(text, separators=(',', ':')),
            scale=f.make('geometry_msgs/msg/Vector3', x=0.05, y=0.05, z=0.05),
            color=color(0.5, 0.5, 0.5, 0.6),
            points=[f.make('geometry_msgs/msg/Point', x=float(a), y=float(b), z=0.0)
                    for a, b in segments]))
    x, y, theta = (float(v) for v in detections.origin)
    view = detections.view
    if len(view):
        markers.append(f.make(
            'visualization_msgs/msg/Marker', header=header(f, stamp, frame_id), ns='view',
            id=0, type=MARKER_POINTS, action=MARKER_ADD, pose=pose(x, y, theta),
            scale=f.make('geometry_msgs/msg/Vector3', x=0.03, y=0.03, z=0.03),
            color=color(0.3, 0.6, 1.0, 0.5),
            points=[f.make('geometry_msgs/msg/Point', x=a, y=b, z=c)
                    for a, b, c in _view_points(view)]))
    markers.append(f.make(
        'visualization_msgs/msg/Marker', header=header(f, stamp, frame_id), ns='scanner',
        id=0, type=MARKER_ARROW, action=MARKER_ADD, pose=pose(x, y, theta),
        scale=f.make('geometry_msgs/msg/Vector3', x=0.4, y=0.05, z=0.05),
        color=color(0.2, 0.8, 0.2, 0.8),
        text=json.dumps({'restarted': bool(detections.restarted)}, separators=(',', ':'))))
    return f.make('visualization_msgs/msg/MarkerArray', markers=markers)


def _numbers(values, n: int) -> list[float] | None:
    """``values`` as ``n`` floats (a non-number as 0), None unless a list of ``n``."""
    if not isinstance(values, list) or len(values) != n:
        return None
    return [float(v) if isinstance(v, (int, float)) else 0.0 for v in values]


def _view_points(view) -> list[tuple[float, float, float]]:
    """The ``view`` marker's points of a ``core.detections.View`` (see
    :func:`detections_to_marker_array`)."""
    bearing = np.asarray(view.bearing, dtype=float).reshape(-1)
    reach = np.asarray(view.reach, dtype=float).reshape(-1)
    seen = np.isfinite(reach)
    r = np.where(seen, reach, 1.0)
    background = np.asarray(view.background, dtype=bool).reshape(-1)
    on_background = seen & background if background.shape == seen.shape else 0.0
    code = np.where(seen, 0.5 * on_background, np.where(reach > 0, 1.0, -1.0))
    return np.column_stack((r * np.cos(bearing), r * np.sin(bearing), code)).tolist()


def _view_of_points(points: np.ndarray):
    """The ``core.detections.View`` of the ``view`` marker's points (k, 3)."""
    from laser_tracker.core.detections import View

    x, y, z = points.T
    reach = np.where(z > 0.75, np.inf, np.where(z < -0.5, -np.inf, np.hypot(x, y)))
    return View(bearing=np.arctan2(y, x), reach=reach, background=(z > 0.25) & (z <= 0.75))


def detections_from_marker_array(msg):
    """The ``blobs`` topic MarkerArray -> ``core.detections.Detections``.

    Raises ValueError if the array has no ``scanner`` marker (not a message of the
    ``blobs`` topic).
    """
    from laser_tracker.core.detections import Blobs, Detections, People, Segments, View

    rows, origin, stamp, frame_id, restarted = [], None, math.nan, 'odom', False
    stamp_ns = None
    persons, segments, view = [], [], None
    for m in msg.markers:
        if m.action != MARKER_ADD:
            continue
        if m.ns == 'scanner':
            p = m.pose
            origin = (p.position.x, p.position.y, yaw_from_quaternion(p.orientation))
            stamp, frame_id = stamp_to_sec(m.header.stamp), str(m.header.frame_id)
            stamp_ns = stamp_to_ns(m.header.stamp)
            try:
                restarted = bool(json.loads(m.text).get('restarted', False)) if m.text else False
            except (json.JSONDecodeError, AttributeError):
                restarted = False
        elif m.ns == 'blobs' and m.type == MARKER_CYLINDER:
            try:
                extra = json.loads(m.text) if m.text else {}
            except json.JSONDecodeError:
                extra = {}
            structure = extra.get('structure')
            rows.append((m.pose.position.x, m.pose.position.y, int(extra.get('cells', 1)),
                         float(m.scale.x), math.nan if structure is None else float(structure)))
        elif m.ns == 'persons' and m.type == MARKER_CYLINDER:
            try:
                extra = json.loads(m.text) if m.text else {}
            except json.JSONDecodeError:
                extra = {}
            extra = extra if isinstance(extra, dict) else {}
            spread = extra.get('spread')
            persons.append((m.pose.position.x, m.pose.position.y,
                            number(extra, 'confidence', 1.0),
                            1.0 if extra.get('free') is True else 0.0,
                            math.nan if spread is None else number(extra, 'spread'),
                            1.0 if extra.get('static') is True else 0.0))
        elif m.ns == 'segments' and m.type == MARKER_POINTS:
            points = [(p.x, p.y) for p in m.points]
            try:
                extra = json.loads(m.text) if m.text else {}
            except json.JSONDecodeError:
                extra = {}
            extra = extra if isinstance(extra, dict) else {}
            leg, occupied = (_numbers(extra.get(k), len(points)) for k in ('leg', 'occupied'))
            segments.extend((x, y, v, w) for (x, y), v, w in zip(
                points, leg if leg is not None else [0.0] * len(points),
                occupied if occupied is not None else [math.nan] * len(points)))
        elif m.ns == 'view' and m.type == MARKER_POINTS:
            view = _view_of_points(np.array([(p.x, p.y, p.z) for p in m.points],
                                            dtype=float).reshape(-1, 3))
    if origin is None:
        raise ValueError('MarkerArray has no scanner marker: not a blobs message')
    arr = np.array(rows, dtype=float).reshape(-1, 5)
    people = np.array(persons, dtype=float).reshape(-1, 6)
    seg = np.array(segments, dtype=float).reshape(-1, 4)
    return Detections(
        stamp=stamp, origin=np.array(origin, dtype=float),
        blobs=Blobs(xy=arr[:, :2].copy(), cells=arr[:, 2].astype(np.int64),
                    extent=arr[:, 3].copy(), structure=arr[:, 4].copy()),
        people=People(xy=people[:, :2].copy(), confidence=people[:, 2].copy(),
                      free=people[:, 3] > 0.5, spread=people[:, 4].copy(),
                      static=people[:, 5] > 0.5),
        segments=Segments(xy=seg[:, :2].copy(), leg=seg[:, 2].copy(),
                          occupied=seg[:, 3].copy() if not np.isnan(seg[:, 3]).any()
                          else np.zeros(0)),
        view=view if view is not None else View(),
        frame_id=frame_id, restarted=restarted, stamp_ns=stamp_ns)


# ----------------------------------------------------------------------------------- tracks


def tracks_to_objects(tracks, confirmed_only: bool = True) -> list[MovingObject]:
    """``core.hypotheses.Tracks`` -> MovingObjects for the ``tracks`` schema: ``extra`` =
    ``weight``, ``confirmed``, ``samples``, ``kind`` (``person`` / ``object``), ``moving``,
    ``covariance`` ([xx, xy, yy] of the position, m^2)."""
    rows = np.flatnonzero(tracks.confirmed) if confirmed_only else np.arange(len(tracks))
    out = []
    for i in rows:
        c = tracks.covariance[i]
        out.append(MovingObject(
            int(tracks.track_id[i]), float(tracks.position[i, 0]),
            float(tracks.position[i, 1]), float(tracks.velocity[i, 0]),
            float(tracks.velocity[i, 1]),
            {'weight': round(float(tracks.weight[i]), 2),
             'confirmed': bool(tracks.confirmed[i]), 'samples': int(tracks.samples[i]),
             'kind': str(tracks.kind[i]), 'moving': bool(tracks.moving[i]),
             'covariance': [round(float(c[0, 0]), 6), round(float(c[0, 1]), 6),
                            round(float(c[1, 1]), 6)]}))
    return out


def tracker_msgs(factory: MessageFactory, tracks, stamp: float, frame_id: str,
                 stamp_ns: int | None = None):
    """The tracking node's outputs for one frame, stamped exactly (``stamp_ns``):
    ``(tracks, hypotheses, tracks/markers)``: the confirmed tracks and every hypothesis in the
    moving-object schema, and the markers RViz draws (:func:`track_markers`)."""
    f = factory
    confirmed = objects_to_marker_array(f, tracks_to_objects(tracks, True), stamp, frame_id,
                                        'tracks')
    hypotheses = objects_to_marker_array(f, tracks_to_objects(tracks, False), stamp, frame_id,
                                         'hypotheses', color=(0.6, 0.6, 0.6, 0.5))
    markers = track_markers(f, tracks, stamp, frame_id)
    return tuple(restamp_ns(f, msg, stamp_ns) for msg in (confirmed, hypotheses, markers))


# -------------------------------------------------------------------------- what people see

#: Colour (r, g, b) of a track's kind wherever tracks are drawn (RViz markers, animations).
KIND_COLOURS = {'person': (0.85, 0.15, 0.75), 'object': (0.1, 0.55, 0.95)}
#: Opacity of a tentative (not yet confirmed) hypothesis's markers.
TENTATIVE_ALPHA = 0.4
MARKER_LINE_LIST = 5
MARKER_SPHERE_LIST = 7
MARKER_TEXT = 9
TEXT_HEIGHT = 0.3   # m


def track_label(track_id: int, kind: str, speed: float, confirmed: bool) -> str:
    """``"7 person 1.2 m/s"``; a ``?`` after the id while the hypothesis is tentative."""
    return f'{int(track_id)}{"" if confirmed else "?"} {kind} {speed:.1f} m/s'


def _point(f: MessageFactory, x: float, y: float, z: float = 0.0):
    return f.make('geometry_msgs/msg/Point', x=float(x), y=float(y), z=float(z))


def _at(f: MessageFactory, x: float, y: float, z: float = 0.0):
    return f.make('geometry_msgs/msg/Pose', position=_point(f, x, y, z),
                  orientation=f.make('geometry_msgs/msg/Quaternion', x=0.0, y=0.0, z=0.0,
                                     w=1.0))


def _rgba(f: MessageFactory, rgb, alpha: float):
    return f.make('std_msgs/msg/ColorRGBA', r=float(rgb[0]), g=float(rgb[1]), b=float(rgb[2]),
                  a=float(alpha))


def _scale(f: MessageFactory, x: float, y: float, z: float):
    return f.make('geometry_msgs/msg/Vector3', x=float(x), y=float(y), z=float(z))


def track_markers(factory: MessageFactory, tracks, stamp: float, frame_id: str):
    """``core.hypotheses.Tracks`` -> the ``tracks/markers`` MarkerArray that RViz and Foxglove
    draw (for people; programs read ``tracks``).

    A DELETEALL, then per hypothesis a TEXT_VIEW_FACING label (ns ``track_labels``, id = the
    track id, text :func:`track_label`, 0.3 m above the track) and a velocity ARROW (ns
    ``track_velocities``, from the position to where the track will be in one second), in
    the colour of its kind (:data:`KIND_COLOURS`): opaque once confirmed, translucent
    (:data:`TENTATIVE_ALPHA`) while tentative.
    """
    f = factory
    hdr = header(f, stamp, frame_id)
    markers = [f.make('visualization_msgs/msg/Marker', header=hdr, ns='track_labels', id=0,
                      action=MARKER_DELETEALL)]
    for i in range(len(tracks)):
        tid, (x, y), (vx, vy) = int(tracks.track_id[i]), tracks.position[i], tracks.velocity[i]
        confirmed, kind = bool(tracks.confirmed[i]), str(tracks.kind[i])
        rgb = KIND_COLOURS.get(kind, (0.6, 0.6, 0.6))
        alpha = 1.0 if confirmed else TENTATIVE_ALPHA
        markers.append(f.make(
            'visualization_msgs/msg/Marker', header=header(f, stamp, frame_id),
            ns='track_labels', id=tid, type=MARKER_TEXT, action=MARKER_ADD,
            pose=_at(f, x, y, TEXT_HEIGHT), scale=_scale(f, 0.0, 0.0, TEXT_HEIGHT),
            color=_rgba(f, rgb, alpha),
            text=track_label(tid, kind, math.hypot(float(vx), float(vy)), confirmed)))
        markers.append(f.make(
            'visualization_msgs/msg/Marker', header=header(f, stamp, frame_id),
            ns='track_velocities', id=tid, type=MARKER_ARROW, action=MARKER_ADD,
            pose=_at(f, 0.0, 0.0), scale=_scale(f, 0.06, 0.15, 0.15),
            color=_rgba(f, rgb, alpha),
            points=[_point(f, x, y), _point(f, float(x) + float(vx), float(y) + float(vy))]))
    return f.make('visualization_msgs/msg/MarkerArray', markers=markers)


#: OccupancyGrid value of each cell state of ``core.grid`` (UNKNOWN, FREE, OCCUPIED).
OCCUPANCY_OF_CELL = np.array([-1, 0, 100], np.int8)
#: Difference map values: a change by Eq. 1 that no blob reports, a cell that made a blob.
DIFFERENCE_UNREPORTED, DIFFERENCE_REPORTED = 50, 100


def difference_occupancy(detection) -> np.ndarray:
    """A ``core.stages.Detection`` computed with grids -> the difference map in OccupancyGrid
    values (``[ix, iy]``): -1 where the previous grid had no valid data, 0 no change,
    :data:`DIFFERENCE_UNREPORTED` (50) a change by Eq. 1 that the history, the static
    background or the pose gate discarded, :data:`DIFFERENCE_REPORTED` (100) the cells that
    made the blobs."""
    from laser_tracker.core.grid import UNKNOWN

    grid = detection.grid
    out = np.zeros(grid.shape, np.int8)
    if detection.previous is None:
        out[:] = -1
        return out
    out[detection.previous == UNKNOWN] = -1
    if detection.difference is not None:
        out[detection.difference] = DIFFERENCE_UNREPORTED
    if detection.changed_cells is not None and detection.changed_cells.size:
        out.reshape(-1)[detection.changed_cells] = DIFFERENCE_REPORTED
    return out


def occupancy_grid_msg(factory: MessageFactory, values: np.ndarray, resolution: float,
                       stamp: float, frame_id: str):
    """A square grid in the layout of ``core.grid`` (``values[ix, iy]``, ``ix`` along the
    frame's x, centred on the frame's origin), in OccupancyGrid values (-1 unknown, 0..100),
    -> nav_msgs/OccupancyGrid (row-major, x fastest: ``data[iy * n + ix]``; origin = the
    corner of cell (0, 0))."""
    f = factory
    n = int(values.shape[0])
    half = n * float(resolution) / 2.0
    hdr = header(f, stamp, frame_id)
    info = f.make('nav_msgs/msg/MapMetaData', map_load_time=hdr.stamp,
                  resolution=float(resolution), width=n, height=n, origin=_at(f, -half, -half))
    return f.make('nav_msgs/msg/OccupancyGrid', header=hdr, info=info,
                  data=f.int8_array(np.ascontiguousarray(np.asarray(values, np.int8).T)))


#: Colour (r, g, b) of each verdict of the per-frame evaluation markers.
EVALUATION_COLOURS = {'matches': (0.1, 0.8, 0.1), 'misses': (0.9, 0.1, 0.1),
                      'false_positives': (1.0, 0.55, 0.0)}


def evaluation_markers(factory: MessageFactory, stamp: float, frame_id: str, matches,
                       misses, false_positives):
    """One frame of CLEAR MOT verdicts as a MarkerArray: a DELETEALL, then a green LINE_LIST
    (ns ``matches``) from each matched track to its object (``matches`` (K, 4): track x, y,
    object x, y), red spheres (ns ``misses``) on the missed objects and orange spheres (ns
    ``false_positives``) on the false-positive tracks (``misses``, ``false_positives``:
    (M, 2) positions). An empty group has no marker."""
    f = factory
    markers = [f.make('visualization_msgs/msg/Marker', header=header(f, stamp, frame_id),
                      ns='matches', id=0, action=MARKER_DELETEALL)]
    groups = (('matches', MARKER_LINE_LIST, np.asarray(matches, float).reshape(-1, 2), 0.05),
              ('misses', MARKER_SPHERE_LIST, np.asarray(misses, float).reshape(-1, 2), 0.35),
              ('false_positives', MARKER_SPHERE_LIST,
               np.asarray(false_positives, float).reshape(-1, 2), 0.35))
    for ns, kind, points, size in groups:
        if not points.shape[0]:
            continue
        markers.append(f.make(
            'visualization_msgs/msg/Marker', header=header(f, stamp, frame_id), ns=ns, id=0,
            type=kind, action=MARKER_ADD, pose=_at(f, 0.0, 0.0),
            scale=_scale(f, size, size, size), color=_rgba(f, EVALUATION_COLOURS[ns], 0.9),
            points=[_point(f, x, y) for x, y in points]))
    return f.make('visualization_msgs/msg/MarkerArray', markers=markers)
