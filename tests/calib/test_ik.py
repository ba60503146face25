"""Closed-form inverse kinematics of the nominal robot."""

from __future__ import annotations

import numpy as np
import pytest
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


def test_multistart_newton_finds_no_branch_the_closed_form_misses() -> None:
    """Brute force: damped Newton (calib.ik_refine on the nominal model) from 300 random seeds
    per pose; every distinct solution within the limits is among the closed-form ones
    (which include the whole-turn alternatives), and the search finds several branches."""
    from calib import ik_refine

    rng = np.random.default_rng(11)
    limits = robot.JointLimits()
    for q in random_q(rng, 6):
        T = MODEL.fk(X0, q[None])[0]
        closed = ik.solve(MODEL.fk(X0, q[None], flange=True)).q_deg
        seeds = random_q(rng, 300)
        ref = ik_refine.refine(MODEL, X0, T, seeds, max_iter=60, limits=limits)
        found = ref.q_deg[ref.converged]
        assert len(found) > 0
        d = np.abs(found[:, None, :] - closed[None, :, :]).max(axis=2).min(axis=1)
        # near the wrist singularity J4/J6 are ill-conditioned: compare poses there
        assert np.all(d < 1e-4), found[d >= 1e-4]
        distinct = np.unique(np.round(found, 3), axis=0)
        assert len(distinct) >= 2


def test_agrees_with_py_opw_kinematics() -> None:
    pytest.importorskip("py_opw_kinematics")
    from bench.ik import opw_robot, opw_solutions_within_limits

    rob = opw_robot()
    q = random_q(np.random.default_rng(7), 2000)
    T = MODEL.fk(X0, q, flange=True)
    ours = ik.solve(T, turn_alternatives=False)
    theirs = opw_solutions_within_limits(rob, T)
    for i in range(len(q)):
        a, b = ours.for_pose(i), theirs[i]
        assert len(a) == len(b), i
        if len(a):
            d = np.abs(((a[:, None, :] - b[None, :, :]) + 180.0) % 360.0 - 180.0).max(axis=2)
            assert d.min(axis=1).max() < 1e-6 and d.min(axis=0).max() < 1e-6


def test_degenerate_input_never_nan() -> None:
    rng = np.random.default_rng(3)
    T = MODEL.fk(X0, random_q(rng, 50), flange=True)
    T[0, :3, 3] = [0.0, 0.0, 500.0] + 175.0 * T[0, :3, 2]  # wrist centre on the J1 axis
    T[1, :3, 3] = [1e5, 0.0, 0.0]  # far out of reach
    T[2, :3, 3] = np.nan  # garbage in
    T[3] = np.eye(4)  # base origin: inside the J1 axis
    for turns in (True, False):
        sols = ik.solve(T, turn_alternatives=turns)
        assert np.all(np.isfinite(sols.q_deg))
        assert not np.isin([0, 1, 2, 3], sols.pose_index).any()
        assert np.all(np.diff(sols.pose_index) >= 0)  # pose by pose


def test_branch_ids_index_the_turn_shifts() -> None:
    lim = robot.JointLimits()
    q = random_q(np.random.default_rng(8), 200)
    sols = ik.solve(MODEL.fk(X0, q, flange=True))
    shifts = np.array(ik.turn_shifts(lim))
    base = ik.solve(MODEL.fk(X0, q, flange=True), turn_alternatives=False)
    assert set(np.unique(sols.branch // len(shifts))) <= set(range(ik.N_BRANCHES))
    # subtracting the shift gives an angle in [-180, 180]
    unshifted = sols.q_deg - shifts[sols.branch % len(shifts)]
    assert np.all(np.abs(unshifted) <= 180.0 + 1e-9)
    assert len(base.q_deg) <= len(sols.q_deg)


def test_chunks_do_not_change_the_solutions() -> None:
    """The batch is solved in chunks of poses (count, then write): solving more poses than a
    chunk gives, pose by pose, what solving each pose alone gives, in the same order."""
    rng = np.random.default_rng(12)
    n = ik.CHUNK + 37
    T = MODEL.fk(X0, random_q(rng, n), flange=True)
    T[5, :3, 3] = np.nan  # garbage and unreachable poses inside a chunk
    T[ik.CHUNK + 1, :3, 3] = [1e5, 0.0, 0.0]
    for turns in (True, False):
        batch = ik.solve(T, turn_alternatives=turns)
        assert np.all(np.diff(batch.pose_index) >= 0)
        for i in (0, 5, ik.CHUNK - 1, ik.CHUNK, ik.CHUNK + 1, n - 1):
            alone = ik.solve(T[i : i + 1], turn_alternatives=turns)
            mine = batch.pose_index == i
            assert np.array_equal(batch.q_deg[mine], alone.q_deg)
            assert np.array_equal(batch.branch[mine], alone.branch)
        assert not np.isin([5, ik.CHUNK + 1], batch.pose_index).any()
        assert np.bincount(batch.pose_index, minlength=n)[ik.CHUNK - 1 : ik.CHUNK + 1].all()
