"""CARMEN text logs (plain or gzip) read into numpy arrays; pure, no ROS.

Lines understood (everything else, comments ``#`` and unknown messages such as ``PARAM``,
``NEFF``, ``RLASER``, ``RAWLASER*``, is skipped):

* ``FLASER n r0 .. r(n-1) x y theta odom_x odom_y odom_theta ipc_timestamp hostname
  logger_timestamp`` (old logs may end after ``ipc_timestamp``): the front laser; ``x y theta``
  is the laser pose (in the corrected logs: the SLAM-corrected pose), ``odom_*`` the robot's
  odometry pose.
* ``ROBOTLASER1 laser_type start_angle field_of_view angular_resolution maximum_range accuracy
  remission_mode n r0 .. r(n-1) m e0 .. e(m-1) laser_x laser_y laser_theta robot_x robot_y
  robot_theta tv rv forward_safety_dist side_safety_dist turn_axis ipc_timestamp hostname
  logger_timestamp``. When a log has ROBOTLASER1 lines, those are the scans and FLASER lines
  are ignored (CARMEN loggers write both for the same laser).
* ``ODOM x y theta tv rv accel ipc_timestamp hostname logger_timestamp``: the odometry stream.

Beam geometry of FLASER (the line carries none): the SICK's 180 degree field of view, first
beam at -90 degrees. For n = 181 or 361 (and any other n except 180) the beams span the field
of view inclusively: ``angle_increment = pi / (n - 1)``. For n = 180 the CARMEN convention is
1 degree steps from -90 degrees (the last beam at +89 degrees): ``angle_increment = pi / 180``.
ROBOTLASER1 lines carry ``start_angle`` and ``angular_resolution``; those are used.

No return: a SICK reports "nothing seen" as its maximum reading (81.91 in mit-csail, 81.83 in
intel, 50.0 in aces). With ``max_reading=None`` (auto) the log's largest reading is taken as
that value when it occurs at least twice (a saturation value repeats; a genuine far echo
rarely does). For ROBOTLASER1 the line's ``maximum_range`` is used instead. Readings at or
above the no-return value (within 5 mm) are no return; :attr:`CarmenLog.range_max` is that
value, so ``Scan.valid()`` never treats them as obstacles.

Poses: by CARMEN's format the FLASER ``x y theta`` is the pose of the *laser* (the robot pose
moved by ``robot_frontlaser_offset`` along its heading) and ``odom_x odom_y odom_theta`` the
robot's odometry pose. In the corrected logs (intel, aces, freiburg-079) both carry the same
SLAM-corrected pose (freiburg declares a front laser offset of -0.04 m, yet its two poses are
identical), so the corrected pose is taken as the laser's: the scan frame's pose.

Messy time stamps (each kind reported once, with its count, in :attr:`CarmenLog.issues` and
one warning; the rest of the log is used; ``strict=True`` refuses the log instead, with the
file and the first offending line):

* a line stamped negative (or not finite): skipped;
* ODOM lines out of time order: a line stamped before the newest earlier ODOM line is
  inserted in time order when it is at most :data:`REORDER_WINDOW` older; older, or stamped
  exactly 0 after positive stamps (the corrected logs interleave their corrected poses as ODOM
  lines stamped 0), it is dropped. Laser lines out of order are kept in file order (counted;
  ``import-carmen`` writes them in time order);
* stamps printed with too few digits to be distinct (intel's ODOM lines: ``2665.42`` eleven
  times): a run of equal stamps is spread evenly up to the next distinct stamp;
* ODOM lines and the laser lines' odometry fields that disagree (by more than
  :data:`ODOMETRY_TOLERANCE` at the laser stamps): the ODOM lines are used (:meth:`odometry`).

Errors: a malformed line, a file that cannot be read, or a truncated gzip stream raise
:class:`laser_tracker.errors.InputFileError` naming the file and the line number.
"""
from __future__ import annotations

import gzip
import logging
import math
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from laser_tracker.core.scan import Scan
from laser_tracker.errors import InputFileError

log = logging.getLogger(__name__)

#: Readings within this distance below the no-return value count as no return (CARMEN logs
#: print centimetres).
NO_RETURN_TOLERANCE = 0.005
#: An ODOM line at most this much (s) older than the newest earlier one is re-ordered; an
#: older one is dropped.
REORDER_WINDOW = 1.0
#: ODOM lines and laser-line odometry closer than this (m, rad) at a laser stamp agree.
ODOMETRY_TOLERANCE = (0.05, math.radians(2.0))


def flaser_geometry(n_beams: int) -> tuple[float, float]:
    """``(angle_min, angle_increment)`` of an n-beam FLASER line (see the module docstring)."""
    if n_beams < 2:
        raise ValueError(f'a FLASER scan needs at least 2 beams, got {n_beams}')
    if n_beams == 180:
        return -math.pi / 2.0, math.pi / 180.0
    return -math.pi / 2.0, math.pi / (n_beams - 1)


@dataclass
class CarmenLog:
    """The content of a CARMEN log as arrays (N laser lines, M ODOM lines).

    ``stamps`` (N,) ipc time stamps (s) of the laser lines, ``ranges`` (N, beams) the readings
    as logged (no-return readings keep their logged value; see :meth:`scan`),
    ``laser_poses`` (N, 3) the laser pose of each line, ``odom_poses`` (N, 3) the robot's
    odometry pose of each line; ``odom_stamps`` (M,), ``odom_stream`` (M, 3) and
    ``odom_velocities`` (M, 2: tv, rv) the usable ODOM lines in time order with distinct
    stamps (see the module docstring); ``line_numbers`` (N,) where each laser line is
    (1-based); ``issues`` what was repaired or dropped, with counts.
    """

    path: str
    kind: str
    stamps: np.ndarray
    ranges: np.ndarray
    angle_min: float
    angle_increment: float
    range_max: float
    laser_poses: np.ndarray
    odom_poses: np.ndarray
    odom_stamps: np.ndarray
    odom_stream: np.ndarray
    odom_velocities: np.ndarray
    line_numbers: np.ndarray
    no_return_value: float | None = None
    skipped: dict = field(default_factory=dict)
    issues: dict = field(default_factory=dict)  # what was repaired or dropped -> count

    def __len__(self) -> int:
        return int(self.stamps.size)

    @property
    def n_beams(self) -> int:
        return int(self.ranges.shape[1]) if self.ranges.ndim == 2 else 0

    def no_return(self) -> np.ndarray:
        """(N, beams) bool: readings that mean "nothing seen" (at or above ``range_max``)."""
        with np.errstate(invalid='ignore'):
            return self.ranges >= self.range_max - NO_RETURN_TOLERANCE

    def scan_ranges(self) -> np.ndarray:
        """(N, beams) ranges with no-return readings as +inf (REP 117)."""
        out = self.ranges.copy()
        out[self.no_return()] = np.inf
        return out

    def scan(self, i: int, frame_id: str = 'laser', ranges: np.ndarray | None = None,
             stamp: float | None = None) -> Scan:
        """Laser line ``i`` as a :class:`Scan` (no-return readings as +inf), stamped with its
        line's time stamp unless ``stamp`` is given."""
        if ranges is None:
            r = self.ranges[i].copy()
            with np.errstate(invalid='ignore'):
                r[r >= self.range_max - NO_RETURN_TOLERANCE] = np.inf
        else:
            r = ranges[i]
        return Scan(stamp=float(self.stamps[i] if stamp is None else stamp), ranges=r,
                    angle_min=self.angle_min, angle_increment=self.angle_increment,
                    range_min=0.0, range_max=self.range_max, frame_id=frame_id)

    def scans(self, frame_id: str = 'laser') -> Iterator[Scan]:
        ranges = self.scan_ranges()
        for i in range(len(self)):
            yield self.scan(i, frame_id, ranges)

    def odometry(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
        """``(stamps, poses, velocities, source)``: ODOM lines if any, else FLASER odometry."""
        if self.odom_stamps.size:
            return self.odom_stamps, self.odom_stream, self.odom_velocities, 'ODOM'
        return self.stamps, self.odom_poses, np.zeros((len(self), 2)), self.kind


def _open_text(path: Path):
    with open(path, 'rb') as fh:
        magic = fh.read(2)
    if magic == b'\x1f\x8b':
        return gzip.open(path, 'rt', encoding='ascii', errors='replace')
    return open(path, encoding='ascii', errors='replace')


#: The first word of the lines of a CARMEN log (messages and parameters).
CARMEN_WORDS = frozenset({'FLASER', 'RLASER', 'LASER3', 'LASER4', 'ROBOTLASER1', 'ROBOTLASER2',
                          'RAWLASER1', 'RAWLASER2', 'RAWLASER3', 'RAWLASER4', 'ODOM',
                          'TRUEPOS', 'PARAM', 'NEFF', 'SYNC', 'GPSNMEA'})


def looks_like_carmen(path: str | Path, lines: int = 20) -> bool:
    """Whether the file at ``path`` (plain or gzip) is a CARMEN log: its first ``lines``
    lines that are not comments start with a CARMEN message name."""
    try:
        with _open_text(Path(path)) as fh:
            head = fh.read(65536)      # a binary file may have no line ends at all
    except (OSError, EOFError, zlib.error):
        return False
    text_lines = head.splitlines()
    if len(text_lines) > 1:
        text_lines.pop()               # may be cut off
    words = [line.split(maxsplit=1)[0] for line in text_lines
             if line.strip() and not line.lstrip().startswith('#')][:lines]
    return bool(words) and all(w in CARMEN_WORDS for w in words)


def _floats(tokens, path, lineno, what):
    try:
        return np.array(tokens, dtype=np.float64)
    except ValueError:
        bad = next((t for t in tokens if not _is_float(t)), '?')
        raise InputFileError(path, f'{what}: {bad!r} is not a number',
                             f'line {lineno}') from None


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _count(token, path, lineno, what) -> int:
    try:
        value = int(token)
    except ValueError:
        raise InputFileError(path, f'{what}: expected a beam count, got {token!r}',
                             f'line {lineno}') from None
    if value < 0:
        raise InputFileError(path, f'{what}: negative count {value}', f'line {lineno}')
    return value


class _BadStamp(Exception):
    """A line whose time stamp is negative or not finite (skipped unless strict)."""


def _stamp(value: float, path, lineno, what) -> float:
    if not math.isfinite(value) or value < 0:
        raise _BadStamp(InputFileError(
            path, f'{what}: time stamp must be finite and >= 0, got {value}', f'line {lineno}'))
    return float(value)


def read_carmen(path: str | Path, max_reading: float | None = None,
                strict: bool = False) -> CarmenLog:
    """Parse a CARMEN log (plain or gzip). ``max_reading``: the no-return value (None: auto).

    Raises InputFileError (file + line) for a malformed line, a truncated gzip stream, a log
    without laser lines, or scans whose beam count changes; with ``strict`` also for the
    messy time stamps the module docstring lists (else repaired, counted in ``issues``).
    """
    path = Path(path)
    if not path.exists():
        raise InputFileError(path, 'no such file')
    flaser: list = []      # (lineno, stamp, ranges, laser pose, odom pose)
    robotlaser: list = []  # (lineno, stamp, ranges, laser pose, robot pose, geometry)
    odom: list = []        # (stamp, x, y, theta, tv, rv, lineno)
    skipped: dict[str, int] = {}
    issues: dict[str, int] = {}
    lineno = 0
    try:
        fh = _open_text(path)
    except OSError as exc:
        raise InputFileError(path, f'cannot open: {exc.strerror or exc}') from None
    try:
        with fh:
            for lineno, line in enumerate(fh, start=1):
                tokens = line.split()
                if not tokens or tokens[0].startswith('#'):
                    continue
                kind = tokens[0]
                try:
                    if kind == 'FLASER':
                        flaser.append(_parse_flaser(tokens, path, lineno))
                    elif kind == 'ROBOTLASER1':
                        robotlaser.append(_parse_robotlaser(tokens, path, lineno))
                    elif kind == 'ODOM':
                        odom.append(_parse_odom(tokens, path, lineno) + (lineno,))
                    else:
                        skipped[kind] = skipped.get(kind, 0) + 1
                except _BadStamp as bad:
                    if strict:
                        raise bad.args[0] from None
                    _count_issue(issues, f'{kind} lines stamped negative or not finite: '
                                 'skipped')
    except (EOFError, zlib.error, gzip.BadGzipFile) as exc:
        raise InputFileError(path, f'truncated or damaged gzip stream ({exc})',
                             f'line {lineno + 1}') from None
    except OSError as exc:
        raise InputFileError(path, f'read error: {exc.strerror or exc}',
                             f'line {lineno + 1}') from None

    if robotlaser:
        kind, rows = 'ROBOTLASER1', robotlaser
        if flaser:
            skipped['FLASER'] = len(flaser)
            log.info('%s: %d ROBOTLASER1 and %d FLASER lines; using ROBOTLASER1', path,
                     len(robotlaser), len(flaser))
    elif flaser:
        kind, rows = 'FLASER', flaser
    else:
        raise InputFileError(path, 'no FLASER or ROBOTLASER1 lines (not a CARMEN laser log?)')

    if not rows:
        raise InputFileError(path, f'no {kind} line with a usable time stamp')
    n_beams = rows[0][2].size
    for row in rows:
        if row[2].size != n_beams:
            raise InputFileError(path, f'{kind} with {row[2].size} beams after '
                                 f'{n_beams}-beam scans (one beam count per log)',
                                 f'line {row[0]}')
    ranges = np.vstack([row[2] for row in rows])
    if kind == 'FLASER':
        angle_min, angle_inc = flaser_geometry(n_beams)
        logged_max = None
    else:
        angle_min, angle_inc, logged_max = rows[0][5]

    if max_reading is not None:
        no_return = float(max_reading)
    elif logged_max is not None and logged_max > 0:
        no_return = float(logged_max)
    else:
        no_return = detect_max_reading(ranges)
    if no_return is None:
        finite = ranges[np.isfinite(ranges)]
        range_max = float(finite.max()) + 0.01 if finite.size else 1.0
        log.info('%s: no saturated maximum reading found; every reading is a return '
                 '(range_max %.2f m)', path, range_max)
    else:
        range_max = no_return

    lines = np.array([row[0] for row in rows], dtype=np.int64)
    stamps = np.array([row[1] for row in rows])
    back = np.flatnonzero(np.diff(stamps) < 0)
    if back.size:
        if strict:
            raise InputFileError(path, f'{kind} stamp {stamps[back[0] + 1]} is before the '
                                 f'previous laser line\'s ({stamps[back[0]]})',
                                 f'line {lines[back[0] + 1]}')
        _count_issue(issues, f'{kind} lines stamped before the previous laser line: kept '
                     'in file order', int(back.size))
    stamps = _spread_equal_stamps(stamps, path, lines, kind, strict, issues)
    odom_arr, odom_lines = _clean_odometry(odom, path, strict, issues)
    laser_poses = np.vstack([row[3] for row in rows])
    odom_poses = np.vstack([row[4] for row in rows])
    if odom_arr.shape[0] >= 2:
        _compare_odometry(stamps, odom_poses, odom_arr, kind, issues)
    for message, count in issues.items():
        log.warning('%s: %d %s', path, count, message)
    return CarmenLog(
        path=str(path), kind=kind, stamps=stamps,
        ranges=ranges, angle_min=float(angle_min), angle_increment=float(angle_inc),
        range_max=float(range_max), laser_poses=laser_poses, odom_poses=odom_poses,
        odom_stamps=odom_arr[:, 0].copy(), odom_stream=odom_arr[:, 1:4].copy(),
        odom_velocities=odom_arr[:, 4:6].copy(), line_numbers=lines,
        no_return_value=no_return, skipped=skipped, issues=issues)


def _count_issue(issues: dict, message: str, n: int = 1) -> None:
    issues[message] = issues.get(message, 0) + n


def _spread_equal_stamps(stamps: np.ndarray, path, lines, kind: str, strict: bool,
                         issues: dict) -> np.ndarray:
    """Runs of equal consecutive stamps spread evenly up to the next distinct stamp (the last
    run by the median step); ``strict``: an error at the first repeated stamp."""
    same = np.flatnonzero(np.diff(stamps) == 0)
    if not same.size:
        return stamps
    if strict:
        raise InputFileError(path, f'{kind} stamp {stamps[same[0]]} repeats the previous '
                             f'{kind} line\'s (stamps printed with too few digits?)',
                             f'line {lines[same[0] + 1]}')
    _count_issue(issues, f'{kind} lines share their time stamp with the previous {kind} line '
                 '(printed with too few digits?): spread evenly up to the next stamp',
                 int(same.size))
    out = stamps.astype(float).copy()
    n = stamps.size
    i = 0
    while i < n:
        j = i
        while j + 1 < n and stamps[j + 1] == stamps[i]:
            j += 1
        if j > i:
            if j + 1 < n and stamps[j + 1] > stamps[i]:
                width = stamps[j + 1] - stamps[i]
            else:  # the last run: the log's mean spacing per line so far
                width = (j - i + 1) * ((stamps[i] - stamps[0]) / i if i else 0.01)
            out[i:j + 1] = stamps[i] + width * np.arange(j - i + 1) / (j - i + 1)
        i = j + 1
    return out


def _clean_odometry(odom: list, path, strict: bool, issues: dict):
    """ODOM rows in time order with distinct stamps: (M, 6) array and their line numbers."""
    kept: list = []
    newest = -math.inf
    n_sorted = n_dropped = n_unstamped = 0
    for row in odom:
        stamp, lineno = row[0], row[6]
        if stamp < newest:
            if strict:
                raise InputFileError(path, f'ODOM stamp {stamp} is before an earlier ODOM '
                                     f'line\'s ({newest})', f'line {lineno}')
            if stamp == 0.0:
                n_unstamped += 1
                continue
            if newest - stamp > REORDER_WINDOW:
                n_dropped += 1
                continue
            n_sorted += 1
        else:
            newest = stamp
        kept.append(row)
    if n_unstamped:
        _count_issue(issues, 'ODOM lines stamped 0 after later ones (no time stamp; the '
                     'corrected logs interleave their corrected poses so): dropped', n_unstamped)
    if n_dropped:
        _count_issue(issues, f'ODOM lines stamped more than {REORDER_WINDOW:g} s before an '
                     'earlier ODOM line: dropped', n_dropped)
    if n_sorted:
        _count_issue(issues, 'ODOM lines out of time order: sorted', n_sorted)
    if not kept:
        return np.zeros((0, 6)), np.zeros(0, dtype=np.int64)
    arr = np.array([r[:6] for r in kept], dtype=np.float64)
    lines = np.array([r[6] for r in kept], dtype=np.int64)
    order = np.argsort(arr[:, 0], kind='stable')
    arr, lines = arr[order], lines[order]
    arr[:, 0] = _spread_equal_stamps(arr[:, 0], path, lines, 'ODOM', strict, issues)
    return arr, lines


def _compare_odometry(stamps, laser_odom, odom_arr, kind: str, issues: dict) -> None:
    """Count the laser lines whose odometry fields disagree with the ODOM lines there."""
    t = odom_arr[:, 0]
    inside = (stamps >= t[0]) & (stamps <= t[-1])
    if not inside.any():
        return
    q = stamps[inside]
    x = np.interp(q, t, odom_arr[:, 1])
    y = np.interp(q, t, odom_arr[:, 2])
    th = np.interp(q, t, np.unwrap(odom_arr[:, 3]))
    ref = laser_odom[inside]
    dist = np.hypot(x - ref[:, 0], y - ref[:, 1])
    turn = np.abs((th - ref[:, 2] + math.pi) % (2.0 * math.pi) - math.pi)
    bad = (dist > ODOMETRY_TOLERANCE[0]) | (turn > ODOMETRY_TOLERANCE[1])
    if bad.any():
        _count_issue(issues, f'{kind} lines whose odometry fields disagree with the ODOM '
                     f'lines (up to {dist.max():.2f} m, {math.degrees(turn.max()):.1f} deg): '
                     'a raw log\'s odometry is taken from the ODOM lines',
                     int(np.count_nonzero(bad)))


def detect_max_reading(ranges: np.ndarray) -> float | None:
    """The saturation value of a log: its largest reading if that occurs at least twice."""
    finite = ranges[np.isfinite(ranges)]
    if finite.size == 0:
        return None
    top = float(finite.max())
    if np.count_nonzero(finite >= top - 1e-9) >= 2:
        return top
    return None


def _parse_flaser(tokens, path, lineno):
    if len(tokens) < 2:
        raise InputFileError(path, 'FLASER line without a beam count', f'line {lineno}')
    n = _count(tokens[1], path, lineno, 'FLASER')
    if n < 2:
        raise InputFileError(path, f'FLASER with {n} beams (need at least 2)', f'line {lineno}')
    tail = len(tokens) - 2 - n - 6
    if tail not in (1, 3):
        raise InputFileError(
            path, f'FLASER with {n} beams needs {n + 9} or {n + 11} fields, got {len(tokens)} '
            f'(line cut short or wrong beam count?)', f'line {lineno}')
    values = _floats(tokens[2:2 + n + 7], path, lineno, 'FLASER')
    if tail == 3:
        _floats(tokens[-1:], path, lineno, 'FLASER logger timestamp')
    ranges = values[:n]
    poses = values[n:n + 6]
    if not np.all(np.isfinite(poses)):
        raise InputFileError(path, 'FLASER pose is not finite', f'line {lineno}')
    stamp = _stamp(values[n + 6], path, lineno, 'FLASER')
    return lineno, stamp, ranges, poses[:3].copy(), poses[3:6].copy()


def _parse_robotlaser(tokens, path, lineno):
    if len(tokens) < 10:
        raise InputFileError(path, f'ROBOTLASER1 line too short ({len(tokens)} fields)',
                             f'line {lineno}')
    head = _floats(tokens[2:8], path, lineno, 'ROBOTLASER1 header')
    start, fov, res, max_range = (float(v) for v in head[:4])
    n = _count(tokens[8], path, lineno, 'ROBOTLASER1')
    if n < 2 or len(tokens) < 10 + n:
        raise InputFileError(path, f'ROBOTLASER1 with {n} beams but {len(tokens)} fields',
                             f'line {lineno}')
    m = _count(tokens[9 + n], path, lineno, 'ROBOTLASER1 remissions')
    expected = 24 + n + m
    if len(tokens) != expected:
        raise InputFileError(path, f'ROBOTLASER1 with {n} beams and {m} remissions needs '
                             f'{expected} fields, got {len(tokens)}', f'line {lineno}')
    ranges = _floats(tokens[9:9 + n], path, lineno, 'ROBOTLASER1 ranges')
    rest = _floats(tokens[10 + n + m:10 + n + m + 12], path, lineno, 'ROBOTLASER1')
    if not (math.isfinite(start) and math.isfinite(res) and res != 0.0):
        raise InputFileError(path, f'ROBOTLASER1 bad angles (start {start}, resolution {res})',
                             f'line {lineno}')
    laser_pose, robot_pose = rest[0:3], rest[3:6]
    if not (np.all(np.isfinite(laser_pose)) and np.all(np.isfinite(robot_pose))):
        raise InputFileError(path, 'ROBOTLASER1 pose is not finite', f'line {lineno}')
    stamp = _stamp(rest[11], path, lineno, 'ROBOTLASER1')
    return lineno, stamp, ranges, laser_pose.copy(), robot_pose.copy(), (start, res, max_range)


def _parse_odom(tokens, path, lineno):
    if len(tokens) not in (8, 10):
        raise InputFileError(path, f'ODOM needs 10 fields (x y theta tv rv accel timestamp '
                             f'hostname logger_timestamp), got {len(tokens)}', f'line {lineno}')
    values = _floats(tokens[1:8], path, lineno, 'ODOM')
    if not np.all(np.isfinite(values[:5])):
        raise InputFileError(path, 'ODOM value is not finite', f'line {lineno}')
    stamp = _stamp(values[6], path, lineno, 'ODOM')
    return (stamp, values[0], values[1], values[2], values[3], values[4])
