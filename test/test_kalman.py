"""Kalman filters: the paper's equations (9)-(13) against a hand computation, vectorisation,
and the constant-velocity alternative."""
from __future__ import annotations

import numpy as np
import pytest

from laser_tracker.core.kalman import (KalmanConfig, TrackFilter, cv_predict, cv_update,
                                       predict_velocity, update_velocity)


def test_paper_equations_by_hand():
    q, r = 0.0005, 0.006
    x = np.array([[1.0, 0.0]])
    P = np.array([[[0.006, 0.0], [0.0, 0.006]]])
    z = np.array([[1.2, 0.1]])
    x_pred, P_pred = predict_velocity(x, P, q)           # Eq. 9, 10
    assert np.allclose(x_pred, x) and np.allclose(P_pred[0], 0.0065 * np.eye(2))
    x_new, P_new = update_velocity(x_pred, P_pred, z, r)  # Eq. 13, 11, 12
    k = 0.0065 / (0.0065 + 0.006)                         # 0.52
    assert np.allclose(x_new[0], [1.0 + k * 0.2, k * 0.1])
    assert np.allclose(P_new[0], (1 - k) * 0.0065 * np.eye(2))


def test_general_covariances_match_the_matrix_formulas():
    rng = np.random.default_rng(2)
    k = 7
    A = rng.normal(size=(k, 2, 2))
    P = A @ A.transpose(0, 2, 1) + 0.01 * np.eye(2)
    x = rng.normal(size=(k, 2))
    z = rng.normal(size=(k, 2))
    xv, Pv = update_velocity(x, P, z, 0.3)
    for i in range(k):                                    # one at a time, textbook form
        K = P[i] @ np.linalg.inv(P[i] + 0.3 * np.eye(2))
        assert np.allclose(xv[i], x[i] + K @ (z[i] - x[i]))
        assert np.allclose(Pv[i], (np.eye(2) - K) @ P[i])


def test_the_compiled_filter_equals_numpys_stacked_matrix_formulas_bit_for_bit():
    """The kernels add their 2 x 2 products as numpy's BLAS does (see kalman.py): the numbers
    are those of the stacked numpy formulation they replaced."""
    rng = np.random.default_rng(3)
    for k in (1, 2, 5, 40):
        A = rng.normal(size=(k, 2, 2))
        P = A @ A.transpose(0, 2, 1) * 0.01
        x, z = rng.normal(size=(k, 2)), rng.normal(size=(k, 2))
        xp, Pp = predict_velocity(x, P, 0.0005)
        assert np.array_equal(Pp, P + 0.0005 * np.eye(2))
        S = Pp + 0.006 * np.eye(2)
        inv = S[:, ::-1, ::-1].transpose(0, 2, 1) * np.array([[1.0, -1.0], [-1.0, 1.0]])
        inv /= (S[:, 0, 0] * S[:, 1, 1] - S[:, 0, 1] * S[:, 1, 0])[:, None, None]
        K = Pp @ inv
        xv, Pv = update_velocity(xp, Pp, z, 0.006)
        assert np.array_equal(xv, xp + (K @ (z - xp)[:, :, None])[:, :, 0])
        assert np.array_equal(Pv, Pp - K @ Pp)


def test_steady_state_gain_of_the_paper_parameters():
    """With Q = 0.0005 I and R = 0.006 I the gain settles at 0.25: velocity is an average of
    the last few displacements (legs alternating still give a smooth velocity)."""
    P = np.array([[[0.006, 0.0], [0.0, 0.006]]])
    x = np.zeros((1, 2))
    for _ in range(50):
        xp, Pp = predict_velocity(x, P, 0.0005)
        gain = Pp[0, 0, 0] / (Pp[0, 0, 0] + 0.006)
        x, P = update_velocity(xp, Pp, np.ones((1, 2)), 0.006)
    assert gain == pytest.approx(0.25, abs=1e-3)


@pytest.mark.parametrize('mode', ['paper', 'cv'])
def test_filter_follows_a_constant_velocity_target(mode):
    f = TrackFilter(KalmanConfig(mode=mode))
    dt, v = 0.2, np.array([0.8, -0.5])
    rng = np.random.default_rng(5)
    pos = lambda t: np.array([1.0, 2.0]) + v * t  # noqa: E731
    state, P = f.initial(pos(dt)[None], pos(0.0)[None], np.array([dt]))
    t_state = np.array([dt])
    for k in range(2, 30):
        t = k * dt
        blob = pos(t)[None] + rng.normal(0, 0.03, (1, 2))
        pred = f.predict(state, t_state, t)
        assert np.linalg.norm(pred[0] - pos(t)) < 0.2
        state, P, est = f.correct(state, P, t_state, blob, t)
        t_state = np.array([t])
    assert np.allclose(state[0, 2:], v, atol=0.15)


def test_paper_mode_moves_to_the_blob_and_measures_displacement_over_dt():
    f = TrackFilter(KalmanConfig())
    state = np.array([[0.0, 0.0, 1.0, 0.0]])
    P = np.array([[[0.006, 0.0], [0.0, 0.006]]])
    # Two frames later (a coasted frame in between): z = displacement / 0.4 s = (1.0, 0.5).
    state2, P2, est = f.correct(state, f.coast(P), np.array([0.0]), np.array([[0.4, 0.2]]),
                                0.4)
    assert np.allclose(est, [[0.4, 0.2]]) and np.allclose(state2[0, :2], [0.4, 0.2])
    p_pred = 0.006 + 2 * 0.0005                             # coasted frame + this frame
    k = p_pred / (p_pred + 0.006)
    assert np.allclose(state2[0, 2:], [1.0, k * 0.5])


def test_cv_mode_equations():
    x = np.array([[0.0, 0.0, 1.0, 0.0]])
    P = np.eye(4)[None] * 0.1
    xp, Pp = cv_predict(x, P, np.array([0.5]), 0.0)
    assert np.allclose(xp[0], [0.5, 0.0, 1.0, 0.0])
    F = np.eye(4)
    F[0, 2] = F[1, 3] = 0.5
    assert np.allclose(Pp[0], F @ P[0] @ F.T)
    xu, Pu = cv_update(xp, Pp, np.array([[0.6, 0.0]]), 0.01)
    H = np.hstack((np.eye(2), np.zeros((2, 2))))
    K = Pp[0] @ H.T @ np.linalg.inv(H @ Pp[0] @ H.T + 0.01 * np.eye(2))
    assert np.allclose(xu[0], xp[0] + K @ (np.array([0.6, 0.0]) - xp[0, :2]))
    assert np.allclose(Pu[0], (np.eye(4) - K @ H) @ Pp[0])
