"""Synthetic odometry: a noisy copy of a reference trajectory, for benchmarks and imports.

One place for the odometry noise models that ``laser-tracker bench egomotion`` and
``laser-tracker import-carmen --odometry-noise`` give the matcher in place of wheel odometry
(the corrected CARMEN logs carry the SLAM-corrected trajectory, not odometry):

* ``none``: the reference itself.
* ``realistic``: a calibrated wheel odometry. Per step, with ``d`` the distance travelled
  and ``a`` the angle turned: white noise of 2 % of ``d`` on x and on y and of 1 deg per
  metre (``d``) on the heading, plus a slowly drifting systematic error (each an AR(1)
  process with a correlation of ``BIAS_CORRELATION_STEPS`` steps): a scale error (sigma 1 %
  of ``d``), a heading drift per metre (sigma 0.5 deg/m) and a turn-scale error (sigma 1 % of
  ``a``, a mis-calibrated wheelbase). A platform standing still gets no odometry motion.
* ``poor``: white noise of 5 cm, 5 cm and 2 deg per step whatever the motion (the protocol
  the intel and aces figures were first measured with).

Increments are in the frame of the pose they start from (``geometry.between``).
"""
from __future__ import annotations

import math

import numpy as np

from laser_tracker.core.geometry import between, compose

MODELS = ('none', 'realistic', 'poor')

#: ``poor``: white noise per step (x m, y m, theta rad)
POOR_SIGMA = (0.05, 0.05, math.radians(2.0))
#: ``realistic``: white translation noise per metre, white heading noise per metre
REALISTIC_XY_PER_M = 0.02
REALISTIC_THETA_PER_M = math.radians(1.0)
#: ``realistic``: stationary sigmas of the drifting biases: scale, heading per metre, turn scale
REALISTIC_BIAS = (0.01, math.radians(0.5), 0.01)
BIAS_CORRELATION_STEPS = 100.0


def noisy_increments(reference: np.ndarray, model: str, seed: int = 0) -> np.ndarray:
    """Increments (N, 3): the reference increments (N, 3) with ``model``'s noise."""
    reference = np.asarray(reference, dtype=float).reshape(-1, 3)
    if model not in MODELS:
        raise ValueError(f'unknown odometry noise model {model!r} (one of {", ".join(MODELS)})')
    rng = np.random.default_rng(seed)
    if model == 'none':
        return reference.copy()
    if model == 'poor':
        return reference + rng.normal(0.0, 1.0, reference.shape) * np.array(POOR_SIGMA)
    n = reference.shape[0]
    d = np.hypot(reference[:, 0], reference[:, 1])
    a = reference[:, 2]
    white = rng.normal(0.0, 1.0, (n, 3))
    bias = _ar1(rng, n, BIAS_CORRELATION_STEPS) * np.array(REALISTIC_BIAS)
    out = reference.copy()
    out[:, :2] *= (1.0 + bias[:, 0])[:, None]
    out[:, :2] += white[:, :2] * (REALISTIC_XY_PER_M * d)[:, None]
    out[:, 2] += (bias[:, 1] * d + bias[:, 2] * a + white[:, 2] * REALISTIC_THETA_PER_M * d)
    return out


def _ar1(rng, n: int, correlation_steps: float) -> np.ndarray:
    """(n, 3) unit-variance AR(1) sequences (independent columns)."""
    phi = math.exp(-1.0 / correlation_steps)
    drive = rng.normal(0.0, 1.0, (n, 3)) * math.sqrt(1.0 - phi * phi)
    out = np.empty((n, 3))
    state = rng.normal(0.0, 1.0, 3)
    for k in range(n):
        state = phi * state + drive[k]
        out[k] = state
    return out


def increments_of(poses: np.ndarray) -> np.ndarray:
    """(N - 1, 3) relative motions between consecutive poses (N, 3)."""
    poses = np.asarray(poses, dtype=float)
    return np.array([between(poses[i - 1], poses[i]) for i in range(1, len(poses))]
                    ).reshape(-1, 3)


def chain(start, increments: np.ndarray) -> np.ndarray:
    """Poses (N + 1, 3): ``start`` then the increments composed one after the other."""
    poses = [np.asarray(start, dtype=float)]
    for inc in np.asarray(increments, dtype=float).reshape(-1, 3):
        poses.append(compose(poses[-1], inc))
    return np.array(poses)


def noisy_odometry(reference_poses: np.ndarray, model: str, seed: int = 0) -> np.ndarray:
    """Odometry poses (N, 3) for reference poses (N, 3): same start, noisy increments."""
    reference_poses = np.asarray(reference_poses, dtype=float).reshape(-1, 3)
    if reference_poses.shape[0] == 0:
        return reference_poses.copy()
    inc = noisy_increments(increments_of(reference_poses), model, seed)
    return chain(reference_poses[0], inc)
