"""Kalman filters of the hypotheses (paper Sec. 9), vectorised over all hypotheses.

Paper mode (the reference). The constant-velocity parameters reduce the textbook equations
(4)-(8) to A = H = I on a two-dimensional state, Equations (9)-(13)::

    x-  = x(t-1)                 (9)      P-  = P(t-1) + Q          (10)
    K   = P- (P- + R)^-1         (13)     x   = x- + K (z - x-)      (11)
    P   = (I - K) P-             (12)

with Q = 0.0005 I and R = 0.006 I (Eq. 14, 15). Following METHOD.md Sec. 6 the state is the
target's *velocity* and z the velocity measured from the supporting blob's displacement since
the hypothesis' last supporting blob; the position prediction is that blob's position plus
velocity times the elapsed time, and a supported hypothesis moves to its blob.

Alternative mode ``cv``: the full constant-velocity filter on [x, y, vx, vy] with the blob
position as measurement (white-acceleration process noise), measured against the paper mode
in README.md (Results).

Every function takes stacked arrays: states (k, d) and covariances (k, d, d); there is no
per-hypothesis Python loop. :class:`TrackFilter` gives the tracker one interface over both
modes: a state row is always ``[px, py, vx, vy]`` valid at the hypothesis' ``t_state``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from laser_tracker.config import param
from laser_tracker.core import jit
from laser_tracker.core.jit import fma


@dataclass(frozen=True)
class KalmanConfig:
    """Filter of each hypothesis (node ``tracking``, ``kalman.*``)."""

    mode: str = param('paper', "'paper': state = 2D velocity, A = H = I (Eq. 9-13), z = blob "
                      "displacement / dt; 'cv': state [x, y, vx, vy] constant velocity, "
                      'z = blob position.', choices=('paper', 'cv'))
    q: float = param(0.0005, 'Paper mode: process noise Q = q I per step (Eq. 14).',
                     min=0.0, max=100.0)
    r: float = param(0.006, 'Paper mode: measurement noise R = r I (Eq. 15).',
                     min=1e-9, max=100.0)
    cv_accel_noise: float = param(0.5, 'cv mode: white-acceleration spectral density '
                                  '(m^2/s^3) of the process noise.', min=0.0, max=1000.0)
    cv_position_noise: float = param(0.01, 'cv mode: variance (m^2) of a blob centroid as a '
                                     'measurement of the target position.', min=1e-9,
                                     max=100.0)
    position_variance: float = param(0.01, 'Paper mode: variance (m^2) of a supporting blob '
                                     "as the target's position, for the position covariance "
                                     'the tracks report (the filter itself estimates only '
                                     'the velocity).', min=1e-9, max=100.0)


_I2 = np.eye(2)
_I2.flags.writeable = False
_ADJUGATE_SIGNS = np.array([[1.0, -1.0], [-1.0, 1.0]])
_ADJUGATE_SIGNS.flags.writeable = False


def _inv2(s: np.ndarray) -> np.ndarray:
    """Inverse of stacked 2 x 2 matrices (k, 2, 2): the adjugate over the determinant."""
    out = s[:, ::-1, ::-1].transpose(0, 2, 1) * _ADJUGATE_SIGNS   # [[d, -b], [-c, a]]
    out /= (s[:, 0, 0] * s[:, 1, 1] - s[:, 0, 1] * s[:, 1, 0])[:, None, None]
    return out



# The paper's filter, one hypothesis (row ``i``) at a time, compiled: a stacked numpy
# formulation costs a BLAS call per 2 x 2 product. The products add as numpy's BLAS does
# (each entry of a matrix product a chain of fused multiply-adds from zero, a matrix-vector
# product its terms in reverse), so the numbers are those of the textbook matrix formulas
# evaluated by numpy, bit for bit.

@jit.inline
def _predict_row(P, i, q, Pp):
    """Eq. 10: P- = P + Q (x- = x, Eq. 9)."""
    Pp[0, 0] = P[i, 0, 0] + q
    Pp[0, 1] = P[i, 0, 1] + 0.0
    Pp[1, 0] = P[i, 1, 0] + 0.0
    Pp[1, 1] = P[i, 1, 1] + q


@jit.inline
def _update_row(x0, x1, Pp, z0, z1, r, x_out, P_out, i, col):
    """Eq. 13, 11, 12 with H = I: K = P- (P- + R)^-1, x = x- + K (z - x-), P = P- - K P-;
    the state into ``x_out[i, col:col + 2]``, the covariance into ``P_out[i]``."""
    s00, s01, s10, s11 = Pp[0, 0] + r, Pp[0, 1] + 0.0, Pp[1, 0] + 0.0, Pp[1, 1] + r
    det = s00 * s11 - s01 * s10
    i00, i01, i10, i11 = s11 / det, -s01 / det, -s10 / det, s00 / det
    k00 = fma(Pp[0, 1], i10, fma(Pp[0, 0], i00, 0.0))
    k01 = fma(Pp[0, 1], i11, fma(Pp[0, 0], i01, 0.0))
    k10 = fma(Pp[1, 1], i10, fma(Pp[1, 0], i00, 0.0))
    k11 = fma(Pp[1, 1], i11, fma(Pp[1, 0], i01, 0.0))
    e0, e1 = z0 - x0, z1 - x1
    x_out[i, col] = x0 + fma(k00, e0, fma(k01, e1, 0.0))
    x_out[i, col + 1] = x1 + fma(k10, e0, fma(k11, e1, 0.0))
    P_out[i, 0, 0] = Pp[0, 0] - fma(k01, Pp[1, 0], fma(k00, Pp[0, 0], 0.0))
    P_out[i, 0, 1] = Pp[0, 1] - fma(k01, Pp[1, 1], fma(k00, Pp[0, 1], 0.0))
    P_out[i, 1, 0] = Pp[1, 0] - fma(k11, Pp[1, 0], fma(k10, Pp[0, 0], 0.0))
    P_out[i, 1, 1] = Pp[1, 1] - fma(k11, Pp[1, 1], fma(k10, Pp[0, 1], 0.0))


@jit.kernel
def predict_velocity(x, P, q):
    """Eq. 9 and 10: x- = x, P- = P + Q (stacked)."""
    out = np.empty((P.shape[0], 2, 2))
    for i in range(P.shape[0]):
        _predict_row(P, i, q, out[i])
    return x, out


@jit.kernel
def update_velocity(x_pred, P_pred, z, r):
    """Eq. 13, 11, 12 with H = I (stacked): gain, state and covariance."""
    k = x_pred.shape[0]
    x, P = np.empty((k, 2)), np.empty((k, 2, 2))
    for i in range(k):
        _update_row(x_pred[i, 0], x_pred[i, 1], P_pred[i], z[i, 0], z[i, 1], r, x, P, i, 0)
    return x, P


@jit.kernel
def _predict_positions(state, t_state, t):
    """Rows ``[px, py, vx, vy]`` valid at ``t_state``: the positions at ``t``."""
    out = np.empty((state.shape[0], 2))
    for i in range(state.shape[0]):
        dt = t - t_state[i]
        out[i, 0] = state[i, 0] + state[i, 2] * dt
        out[i, 1] = state[i, 1] + state[i, 3] * dt
    return out


#: No row stands still (``TrackFilter.correct``).
_NOT_STILL = np.zeros(0, bool)


@jit.kernel
def _correct_velocity(state, P, t_state, blob, t, q, r, still, out, P_out):
    """The paper's filter supported by ``blob`` (k, 2) at ``t``: the velocity measured as the
    displacement since ``t_state`` over the time (rows where ``still``, k or 0 values: as
    zero, an object standing at ``blob``), Eq. 9-13; rows ``[blob, velocity]`` into ``out``
    and the covariances into ``P_out`` (which may be ``state`` and ``P``)."""
    k = state.shape[0]
    Pp = np.empty((2, 2))
    for i in range(k):
        z0 = z1 = 0.0
        if not (still.size and still[i]):
            dt = t - t_state[i]
            if dt < 1e-6:
                dt = 1e-6
            z0 = (blob[i, 0] - state[i, 0]) / dt
            z1 = (blob[i, 1] - state[i, 1]) / dt
        _predict_row(P, i, q, Pp)
        _update_row(state[i, 2], state[i, 3], Pp, z0, z1, r, out, P_out, i, 2)
        out[i, 0], out[i, 1] = blob[i, 0], blob[i, 1]


def cv_predict(x: np.ndarray, P: np.ndarray, dt: np.ndarray,
               accel_noise: float) -> tuple[np.ndarray, np.ndarray]:
    """Constant-velocity prediction over ``dt`` (k,) with white-acceleration noise."""
    dt = np.asarray(dt, dtype=float)
    k = x.shape[0]
    F = np.broadcast_to(np.eye(4), (k, 4, 4)).copy()
    F[:, 0, 2] = dt
    F[:, 1, 3] = dt
    x = x.copy()
    x[:, :2] += x[:, 2:] * dt[:, None]
    Q = np.zeros((k, 4, 4))
    q3, q2, q1 = accel_noise * dt ** 3 / 3.0, accel_noise * dt ** 2 / 2.0, accel_noise * dt
    for i in (0, 1):
        Q[:, i, i], Q[:, i + 2, i + 2] = q3, q1
        Q[:, i, i + 2] = Q[:, i + 2, i] = q2
    P = F @ P @ F.transpose(0, 2, 1) + Q
    return x, P


def cv_update(x: np.ndarray, P: np.ndarray, z: np.ndarray,
              r: float) -> tuple[np.ndarray, np.ndarray]:
    """Position measurement update, H = [I 0], R = r I (stacked)."""
    S = P[:, :2, :2] + r * _I2
    K = P[:, :, :2] @ _inv2(S)                       # (k, 4, 2)
    x = x + (K @ (z - x[:, :2])[:, :, None])[:, :, 0]
    P = P - K @ P[:, :2, :]
    return x, P


class TrackFilter:
    """The operations the tracker needs, in either mode, on rows ``[px, py, vx, vy]``."""

    def __init__(self, config: KalmanConfig):
        self.config = config
        self.paper = config.mode == 'paper'
        self.dim = 2 if self.paper else 4

    def initial(self, pos_new: np.ndarray, pos_prev: np.ndarray,
                dt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """State and covariance of hypotheses created from blob pairs (prev -> new over dt)."""
        dt = np.asarray(dt, dtype=float)
        k = pos_new.shape[0]
        vel = (pos_new - pos_prev) / dt[:, None]
        state = np.concatenate((pos_new, vel), axis=1)
        if self.paper:
            # The first velocity measurement, with the measurement's own covariance.
            P = np.zeros((k, 2, 2))
            P[:, 0, 0] = P[:, 1, 1] = self.config.r
        else:
            r = self.config.cv_position_noise
            P = np.zeros((k, 4, 4))
            P[:, 0, 0] = P[:, 1, 1] = r
            P[:, 2, 2] = P[:, 3, 3] = 2.0 * r / dt ** 2
            P[:, 0, 2] = P[:, 2, 0] = P[:, 1, 3] = P[:, 3, 1] = r / dt
        return state, P

    @staticmethod
    def predict(state: np.ndarray, t_state: np.ndarray, t: float) -> np.ndarray:
        """Predicted positions (k, 2) at time ``t``."""
        return _predict_positions(state, t_state, float(t))

    def correct(self, state: np.ndarray, P: np.ndarray, t_state: np.ndarray,
                blob: np.ndarray, t: float, still: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Update with supporting blobs (k, 2) at ``t``; returns state, P, position estimate.
        ``still`` (k,): rows of objects standing at ``blob``, whose velocity is measured as
        zero (:meth:`hold`)."""
        still = _NOT_STILL if still is None else still
        if self.paper:
            k = state.shape[0]
            out, P_out = np.empty((k, 4)), np.empty((k, 2, 2))
            _correct_velocity(state, P, t_state, blob, float(t), self.config.q, self.config.r,
                              still, out, P_out)
            return out, P_out, blob
        dt = np.maximum(t - t_state, 1e-6)
        x, Pp = cv_predict(state, P, dt, self.config.cv_accel_noise)
        x, P_new = cv_update(x, Pp, blob, self.config.cv_position_noise)
        if still.any():
            x[still], P_new[still] = self.hold(state[still], P[still], blob[still])
        return x, P_new, x[:, :2]

    def support(self, hyp, blob: np.ndarray, t: float,
                still: np.ndarray | None = None) -> None:
        """:meth:`correct` of the hypotheses ``hyp`` (``tracking.state.Hypotheses``) in
        place: their state, covariance, position and time."""
        rows = hyp.rows
        if self.paper:
            _correct_velocity(rows['state'], rows['P'], rows['t_state'], blob, float(t),
                              self.config.q, self.config.r,
                              _NOT_STILL if still is None else still, rows['state'],
                              rows['P'])
            rows['position'] = blob
        else:
            rows['state'], rows['P'], rows['position'] = self.correct(
                rows['state'], rows['P'], rows['t_state'], blob, t, still)
        rows['t_state'] = t

    def position_covariance(self, P: np.ndarray, t_state: np.ndarray,
                            t: float) -> np.ndarray:
        """Covariance (k, 2, 2) of the predicted positions at ``t``."""
        dt = (t - np.asarray(t_state, dtype=float))[:, None, None]
        if self.paper:
            return self.config.position_variance * _I2 + P * dt * dt
        return (P[:, :2, :2] + dt * (P[:, :2, 2:] + P[:, 2:, :2]) + dt * dt * P[:, 2:, 2:])

    def hold(self, state: np.ndarray, P: np.ndarray,
             position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A stopped object at ``position`` (k, 2): the velocity measured as zero."""
        if self.paper:
            k = state.shape[0]
            return self.correct(state, P, np.zeros(k), position, 0.0, np.ones(k, bool))[:2]
        x = state.copy()
        x[:, :2] = position
        S = P[:, 2:, 2:] + self.config.cv_position_noise * _I2
        K = P[:, :, 2:] @ _inv2(S)
        x = x + (K @ (-x[:, 2:])[:, :, None])[:, :, 0]
        x[:, :2] = position
        P = P - K @ P[:, 2:, :]
        return x, P

    def coast(self, P: np.ndarray) -> np.ndarray:
        """A frame without support: the prediction step only (paper: P- = P + Q).

        In cv mode the state stays at its last update time and the next prediction spans the
        whole gap, so nothing changes here.
        """
        if self.paper:
            return P + self.config.q * _I2
        return P
