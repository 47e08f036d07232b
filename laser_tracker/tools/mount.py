"""The scanner's mount on the platform (base -> scanner), as a recording knows it.

Odometry gives the pose of the platform's base frame (its ``child_frame_id``); scans are in
the scanner's frame (their ``header.frame_id``). When these differ, ego-motion needs the
transform between them (``ego_motion.mount_x``, ``mount_y``, ``mount_yaw``): a scanner
0.85 m ahead of the base and turned 42 degrees that is taken to sit at the base puts every
odometry prediction off by its lever arm as the robot turns. A recording usually carries the
transform on ``/tf_static`` (or ``/tf``); :func:`recording_mount` finds it, composing a chain
of frames if needed, and says where the mount came from. A scanner hung upside down (its z
axis down) sees the platform's plane mirrored: :attr:`Mount.mirrored`, and the replay turns
its scans over (``Scan.mirrored``) into the scans a level scanner in its place would make.

A recording without an Odometry topic may still carry the odometry as transforms on ``/tf``
(REP 105: ``odom`` -> the base frame, which is how ROS 1 trackers such as leg_tracker read
it); :func:`tf_odometry` finds that transform.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from laser_tracker.conversions import odometry_from_msg, transforms_from_msg
from laser_tracker.core.geometry import compose, inverse

TF_TYPES = ('tf2_msgs/msg/TFMessage', 'tf/msg/tfMessage')
MAX_TF_MESSAGES = 2000     # /tf is read only until the mount is found, or this many messages
#: A scanner tilted more than this (rad) from its base is not taken as level without a word.
MAX_TILT = math.radians(30.0)


@dataclass
class Mount:
    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0
    from_recording: bool = False
    source: str = 'parameters'      # '/tf_static', '/tf', 'parameters', 'same frame', ...
    message: str = ''               # what to tell the user ('' = nothing worth saying)
    base_frame: str | None = None   # the odometry's child frame, when the recording has one
    scan_frame: str | None = None   # the scans' frame, when read
    mirrored: bool = False          # the scanner hangs upside down: its scans are mirrored


def _first_frames(path: Path, scan_topic: str, odom_topic: str | None):
    from laser_tracker.tools.bag import iter_messages

    scan_frame = base_frame = None
    topics = [scan_topic] + ([odom_topic] if odom_topic else [])
    for topic, _, msg in iter_messages(path, topics):
        if topic == scan_topic and scan_frame is None:
            scan_frame = str(msg.header.frame_id).lstrip('/')
        elif topic == odom_topic and base_frame is None:
            base_frame = odometry_from_msg(msg).child_frame_id.lstrip('/')
        if scan_frame is not None and (base_frame is not None or not odom_topic):
            break
    return scan_frame, base_frame


@dataclass
class TfOdometry:
    """The odometry a recording carries on ``topic`` as transforms ``odom_frame`` ->
    ``base_frame``."""
    topic: str
    odom_frame: str
    base_frame: str


def tf_odometry(path: str | Path, scan_topic: str, odom_frame: str) -> TfOdometry | None:
    """The transform on ``/tf`` from ``odom_frame`` to a frame the scans' frame hangs from
    (the scans' frame itself, or one it reaches through the other transforms without passing
    ``odom_frame``); None when the recording has none."""
    from laser_tracker.tools.bag import iter_messages, topics

    path = Path(path)
    odom_frame = odom_frame.lstrip('/')
    info = topics(path)
    dynamic = sorted(t for t, (typ, n) in info.items() if typ in TF_TYPES and n
                     and t != '/tf_static')
    if not dynamic:
        return None
    scan_frame, _ = _first_frames(path, scan_topic, None)
    if not scan_frame:
        return None
    for topic in dynamic:
        children: set[str] = set()
        edges: dict = {}
        for k, (_, _, msg) in enumerate(iter_messages(path, [topic, '/tf_static'])):
            for tr in transforms_from_msg(msg):
                if tr.parent == odom_frame:
                    children.add(tr.child)
                elif tr.child != odom_frame:
                    edges.setdefault((tr.parent, tr.child), (tr.x, tr.y, tr.yaw))
            for child in sorted(children):
                if child == scan_frame or find_transform(edges, child, scan_frame) is not None:
                    return TfOdometry(topic, odom_frame, child)
            if k >= MAX_TF_MESSAGES:
                break
    return None


def path_tilt(tilts: dict, source: str, target: str) -> float:
    """The angle (rad) between the z axes of ``source`` and ``target`` along the frame tree
    of ``tilts`` (``{(parent, child): tilt}``, :class:`PlanarTransform`'s), taking each
    link's tilt about a level axis (a mount pitched or rolled, or upside down); 0 when not
    connected."""
    links = {edge: (math.cos(tilt),) * 2 for edge, tilt in tilts.items()}
    up = _along_tree(links, source, target, 1.0, lambda a, b: a * b)
    return 0.0 if up is None else math.acos(min(max(up, -1.0), 1.0))


def find_transform(edges: dict, source: str, target: str, flips: dict | None = None):
    """Pose of ``target`` in ``source`` from planar edges ``{(parent, child): (x, y, yaw)}``,
    following the frame tree in either direction; None if they are not connected. ``flips``:
    the edges whose child hangs upside down (``{(parent, child): True}``, see
    :func:`mount_between`)."""
    found = mount_between(edges, source, target, flips)
    return None if found is None else found[0]


def mount_between(edges: dict, source: str, target: str, flips: dict | None = None):
    """``(pose, mirrored)`` of ``target`` in ``source`` (None if not connected): an upside-down
    link (``flips``) mirrors its child's plane in its parent's, so a point ``(x, y)`` of
    ``target`` lies at ``pose (+) (x, -y)`` when ``mirrored`` (an odd number of flips on the
    way), at ``pose (+) (x, y)`` otherwise; ``yaw`` is where the target's x axis points."""
    links = {}
    for edge, pose in edges.items():
        link = (np.asarray(pose, dtype=float), bool(flips and flips.get(edge)))
        links[edge] = (link, _inverse_mirrored(link))
    return _along_tree(links, source, target, (np.zeros(3), False), _compose_mirrored)


def _compose_mirrored(a, b):
    """Link ``b`` after link ``a``, each ``(pose, mirrored)``: a mirrored ``a`` turns ``b``'s
    offset and heading over."""
    (pa, fa), (pb, fb) = a, b
    if fa:
        pb = np.array([pb[0], -pb[1], -pb[2]])
    return compose(pa, pb), fa != fb


def _inverse_mirrored(link):
    pose, flipped = link
    inv = inverse(pose)
    return (np.array([inv[0], -inv[1], -inv[2]]) if flipped else inv), flipped


def _along_tree(links: dict, source: str, target: str, start, combine):
    """``start`` combined with each link's value from ``source`` to ``target`` (breadth
    first over ``links``: ``{(parent, child): (value parent -> child, value child ->
    parent)}``); None if they are not connected."""
    graph: dict[str, list] = {}
    for (parent, child), (forward, backward) in links.items():
        graph.setdefault(parent, []).append((child, forward))
        graph.setdefault(child, []).append((parent, backward))
    best = {source: start}
    queue = deque([source])
    while queue:
        frame = queue.popleft()
        if frame == target:
            return best[frame]
        for nxt, step in graph.get(frame, []):
            if nxt not in best:
                best[nxt] = combine(best[frame], step)
                queue.append(nxt)
    return None


def recording_mount(path: str | Path, scan_topic: str, odom_topic: str | None,
                    ego_config, base_frame: str | None = None) -> Mount:
    """The base -> scanner mount to use for a replay of ``path`` (see the module doc): of
    the child frame of ``odom_topic``'s odometry, or of ``base_frame`` (odometry from
    :func:`tf_odometry`)."""
    from laser_tracker.tools.bag import iter_messages, topics

    path = Path(path)
    configured = (ego_config.mount_x, ego_config.mount_y, ego_config.mount_yaw)
    has_config = any(v != 0.0 for v in configured)
    if not odom_topic and base_frame is None:
        return Mount(*configured, source='parameters (no odometry: the mount is not used)')
    scan_frame, odom_base = _first_frames(path, scan_topic, odom_topic)
    base_frame = base_frame or odom_base
    frames = {'base_frame': base_frame, 'scan_frame': scan_frame}
    if not scan_frame or not base_frame or scan_frame == base_frame:
        return Mount(*configured, source='parameters' if has_config else 'same frame',
                     **frames)
    info = topics(path)
    tf_topics = sorted((t for t, (typ, _) in info.items() if typ in TF_TYPES),
                       key=lambda t: (t != '/tf_static', t))
    edges: dict = {}
    tilts: dict = {}
    for topic in tf_topics:
        for k, (_, _, msg) in enumerate(iter_messages(path, [topic])):
            for tr in transforms_from_msg(msg):
                edges.setdefault((tr.parent, tr.child), (tr.x, tr.y, tr.yaw))
                tilts.setdefault((tr.parent, tr.child), tr.tilt)
            flips = {edge: tilt > math.pi / 2 for edge, tilt in tilts.items()}
            found = mount_between(edges, base_frame, scan_frame, flips)
            if found is not None:
                x, y, yaw = (float(v) for v in found[0])
                text = (f'scanner mount from the recording ({topic}, {base_frame} -> '
                        f'{scan_frame}): x={x:.3f} m, y={y:.3f} m, '
                        f'yaw={math.degrees(yaw):.1f} deg')
                if has_config and not np.allclose(configured, (x, y, yaw), atol=1e-6):
                    text += ' (used instead of the configured ego_motion.mount_*)'
                tilt = path_tilt(tilts, base_frame, scan_frame)
                mirrored = found[1] and tilt > math.pi - MAX_TILT
                if mirrored:
                    text += ('; upside down: its scans are mirrored to the frame turned right '
                             'side up')
                elif MAX_TILT < tilt < math.pi - MAX_TILT:
                    text += (f'; warning: the scanner is tilted {math.degrees(tilt):.0f} deg '
                             f'from {base_frame!r}: laser_tracker takes scans as level')
                frames['mirrored'] = mirrored
                return Mount(x, y, yaw, True, topic, text, **frames)
            if k >= MAX_TF_MESSAGES:
                break
    if has_config:
        return Mount(*configured, source='parameters', **frames)
    return Mount(source='unknown', **frames, message=(
        f'warning: the scans are in frame {scan_frame!r} but the odometry is of '
        f'{base_frame!r}, and the recording has no transform between them: the scanner is '
        f'taken to sit at {base_frame!r} (set ego_motion.mount_x, mount_y, mount_yaw)'))
