"""The platform's true motion and the wheel odometry it reports, with realistic errors.

The true pose is a :class:`~laser_tracker.tools.sim.agents.Trajectory` in the world frame (``map``).
Odometry ticks at ``rate_hz``; each tick's true body-frame increment ``(dx, dy, dtheta)`` is
corrupted as wheel odometry is:

* scale error: ``(dx, dy) * (1 + scale_error)``, ``dtheta * (1 + rotation_scale_error)``;
* drift (heading bias): ``+ heading_drift * ds`` rad, ``ds`` the distance travelled in the tick
  (unequal wheel radii curve a straight path), nothing while standing;
* noise: ``dx, dy += N(0, translation_noise^2 * ds)``,
  ``dtheta += N(0, rotation_noise^2 * |dtheta|)`` (variance grows with the distance
  travelled or the angle turned, so it does not depend on the tick rate; none while standing);

and integrated from the true pose at t = 0 (the ``odom`` frame coincides with the world frame
at the start). Latency: the pose that was true at time t reaches the host, and is stamped,
at ``t + latency + U(0, latency_jitter)``. A consumer that takes the stamp at face value sees
the platform ``latency`` late: the paper's "delays and timing errors". The message's twist is
the measured body-frame velocity of the tick.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from laser_tracker.config import param
from laser_tracker.core.geometry import wrap_angle
from laser_tracker.tools.sim.agents import Trajectory


@dataclass(frozen=True)
class OdometryConfig:
    """Simulated wheel odometry (section ``sim.odometry``)."""

    rate_hz: float = param(50.0, 'Odometry messages per second.', min=1.0, max=500.0)
    scale_error: float = param(0.02, 'Relative error of the distance travelled (0.02 = 2 % '
                               'long).', min=-0.5, max=0.5)
    rotation_scale_error: float = param(0.01, 'Relative error of the angle turned.',
                                        min=-0.5, max=0.5)
    heading_drift: float = param(0.005, 'Heading bias per metre travelled (rad/m).',
                                 min=-0.2, max=0.2)
    translation_noise: float = param(0.005, 'Position noise: standard deviation per axis after '
                                     '1 m travelled (m / sqrt(m)).', min=0.0, max=0.2)
    rotation_noise: float = param(0.005, 'Heading noise: standard deviation after turning '
                                  '1 rad (rad / sqrt(rad)).', min=0.0, max=0.2)
    latency: float = param(0.06, 'Delay between a pose being true and its message stamp (s).',
                           min=0.0, max=1.0)
    latency_jitter: float = param(0.008, 'Extra delay, uniform in [0, jitter) (s); below the '
                                  'tick period so stamps stay in order.', min=0.0, max=0.5)
    frame_id: str = param('odom', 'Odometry frame.')
    child_frame_id: str = param('base_link', 'Platform frame.')


@dataclass
class OdometryStream:
    """Simulated odometry: ``true_times`` (K,) when each pose held, ``stamps`` (K,) on the
    messages, ``poses`` (K, 3) in the odom frame, ``twists`` (K, 3) body-frame vx, vy, omega."""

    true_times: np.ndarray
    stamps: np.ndarray
    poses: np.ndarray
    twists: np.ndarray


def simulate_odometry(trajectory: Trajectory, t_end: float, config: OdometryConfig,
                      rng: np.random.Generator, t_start: float = 0.0) -> OdometryStream:
    """Odometry ticks from ``t_start`` to ``t_end`` for the true ``trajectory``."""
    c = config
    if c.latency_jitter >= 1.0 / c.rate_hz:
        raise ValueError('latency_jitter must be below the odometry period')
    count = int(np.floor((t_end - t_start) * c.rate_hz + 1e-9)) + 1
    t = t_start + np.arange(count) / c.rate_hz
    true = trajectory.pose(t)
    # True body-frame increments between ticks.
    d = np.diff(true, axis=0)
    th0 = true[:-1, 2]
    cos0, sin0 = np.cos(th0), np.sin(th0)
    dx = cos0 * d[:, 0] + sin0 * d[:, 1]
    dy = -sin0 * d[:, 0] + cos0 * d[:, 1]
    dth = wrap_angle(d[:, 2])
    ds = np.hypot(dx, dy)
    m = count - 1
    n_xy = rng.standard_normal((m, 2)) * c.translation_noise * np.sqrt(ds)[:, None]
    n_th = rng.standard_normal(m) * c.rotation_noise * np.sqrt(np.abs(dth))
    jitter = rng.random(count) * c.latency_jitter
    mdx = dx * (1.0 + c.scale_error) + n_xy[:, 0]
    mdy = dy * (1.0 + c.scale_error) + n_xy[:, 1]
    mdth = dth * (1.0 + c.rotation_scale_error) + c.heading_drift * ds + n_th
    # Integrate from the true initial pose (odom == world at t_start).
    theta = true[0, 2] + np.concatenate(([0.0], np.cumsum(mdth)))
    ct, st = np.cos(theta[:-1]), np.sin(theta[:-1])
    x = true[0, 0] + np.concatenate(([0.0], np.cumsum(ct * mdx - st * mdy)))
    y = true[0, 1] + np.concatenate(([0.0], np.cumsum(st * mdx + ct * mdy)))
    poses = np.column_stack([x, y, wrap_angle(theta)])
    dt = 1.0 / c.rate_hz
    twists = np.zeros((count, 3))
    twists[1:] = np.column_stack([mdx, mdy, mdth]) / dt
    # Micrometre / microradian rounding: far below every error modelled, and it keeps the
    # bag bytes identical across CPUs whose vectorised sin/cos differ in the last bit.
    poses = np.round(poses, 6)
    twists = np.round(twists, 6)
    stamps = np.round(t + c.latency + jitter, 9)
    return OdometryStream(true_times=t, stamps=stamps, poses=poses, twists=twists)
