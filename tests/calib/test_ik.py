"""Closed-form inverse kinematics of the nominal robot."""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from calib import ik, robot
from calib.model import SystemModel

MODEL = SystemModel(np.eye(4), np.eye(4))
X0 = MODEL.nominal_x()


def random_q(rng: np.random.Generator, n: int) -> np.ndarray:
    lim = robot.JointLimits()
    return rng.uniform(lim.lower_deg, lim.upper_deg, (n, 6))


def test_every_branch_reproduces_the_pose() -> None:
    q = random_q(np.random.default_rng(0), 10_000)
    T = MODEL.fk(X0, q, flange=True)
    sols = ik.solve(T)
    assert np.all(np.isfinite(sols.q_deg)) and robot.JointLimits().contains(sols.q_deg).all()
    T2 = MODEL.fk(X0, sols.q_deg, flange=True)
    err = np.abs(T2 - T[sols.pose_index])
    assert err[:, :3, 3].max() < 1e-9 and err[:, :3, :3].max() < 1e-9
    # the configuration the pose came from is always among the solutions
    d = np.abs(sols.q_deg - q[sols.pose_index]).max(axis=1)
    found = np.zeros(len(q), bool)
    found[sols.pose_index[d < 1e-6]] = True
    assert found.all()


def test_unreachable_and_singular_give_no_solution() -> None:
    T = MODEL.fk(X0, np.array([[0.0, 0.0, 0.0, 0.0, -90.0, 0.0]]), flange=True)
    far = T.copy()
    far[0, :3, 3] = [4000.0, 0.0, 0.0]
    assert len(ik.solve(far).q_deg) == 0
    q_singular = np.array([[10.0, 20.0, 5.0, 30.0, 0.0, 40.0]])
    sols = ik.solve(MODEL.fk(X0, q_singular, flange=True))
    # the wrist-singular branch (J5 = 0) is left out; other arm branches are regular
    assert np.all(np.isfinite(sols.q_deg))
    assert np.all(np.abs(sols.q_deg[:, 4]) > 1e-6)
    assert np.abs(sols.q_deg[:, :3] - q_singular[0, :3]).max(axis=1).min() > 1e-3


def pose_error(qq: np.ndarray, T: np.ndarray) -> np.ndarray:
    Tq = MODEL.fk(X0, qq[None], flange=True)[0]
    return np.concatenate([Tq[:3, 3] - T[:3, 3], 1000.0 * (Tq[:3, :3] - T[:3, :3]).ravel()])


def test_brute_force_numeric_solver_finds_nothing_new() -> None:
    rng = np.random.default_rng(5)
    limits = robot.JointLimits()
    for q in random_q(rng, 3):
        T = MODEL.fk(X0, q[None], flange=True)[0]
        closed = ik.solve(T[None]).q_deg
        for start in random_q(rng, 25):
            sol = least_squares(pose_error, start, args=(T,), xtol=1e-14, ftol=1e-14, gtol=1e-14)
            if np.abs(sol.fun).max() > 1e-6 or not limits.contains(sol.x):
                continue
            assert np.abs(closed - sol.x).max(axis=1).min() < 1e-4, sol.x
