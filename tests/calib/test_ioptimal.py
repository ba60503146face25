"""The workspace criterion "I" (calib.ioptimal): its rank-3 updates against direct inverses,
its index, partial plans, and that a plan chosen with it predicts a smaller workspace error
than the O1 plan at the same positions."""

from __future__ import annotations

import numpy as np
import pytest

from app.config import CellConfig
from app.planning import plan_overrides, run_plan
from app.workspace import weight_for
from calib import detmax
from calib.candidates import ViewGrid, sphere_candidates
from calib.configurations import plan_index, revisit, select_configurations
from calib.ioptimal import WeightedInformation, i_index, observable_projector, workspace_weight
from calib.model import PAPER_30
from calib.plan_settings import PlanSettings

COARSE = ViewGrid(step_deg=20.0)
GRID30 = ViewGrid(step_deg=30.0)


def _blocks(cfg: CellConfig, name: str, grid: ViewGrid = COARSE) -> np.ndarray:
    model = cfg.model()
    x = model.nominal_x()
    cand = sphere_candidates(model, x, cfg.spheres_part_mm[name], grid)
    return model.point_jacobian(x, cand.q_deg, cand.c_sensor_mm, PAPER_30)


def _weight(L: int = 30, seed: int = 0) -> np.ndarray:
    A = np.random.default_rng(seed).normal(size=(40, L))
    return A.T @ A / 40.0


def _trace_value(W: np.ndarray, M: np.ndarray) -> float:
    return float(-np.log(np.trace(W @ np.linalg.inv(M))))


@pytest.mark.parametrize("n_fixed", [0, 18])
def test_woodbury_updates_equal_direct_inverses(cfg: CellConfig, n_fixed: int) -> None:
    """Adding and removing each candidate: the same -log trace(W M^-1) as inverting M, for a
    partial plan (one sphere: W projected onto what the pool reaches) and a full one."""
    J = _blocks(cfg, "P1")[:200]
    fixed = np.concatenate([_blocks(cfg, n)[::97][:6] for n in ("P2", "P3", "P4")])[:n_fixed]
    d = detmax.column_scale(np.concatenate([fixed, J]))
    G = J * d
    info = WeightedInformation(G, fixed * d, _weight() * d[:, None] * d[None, :])
    sel = [3, 50, 90, 120, 160, 199]
    M = info.matrix(sel)
    assert info.log_value(M) == pytest.approx(_trace_value(info.W, M), abs=1e-7)
    fast = info.if_added(sel, M, info.all_rows)
    direct = [_trace_value(info.W, M + G[k].T @ G[k]) for k in range(len(G))]
    assert np.allclose(fast, direct, rtol=0.0, atol=1e-6)
    removed = info.if_removed(sel, M, list(range(len(sel))))
    direct_rm = [_trace_value(info.W, M - G[s].T @ G[s]) for s in sel]
    assert np.allclose(removed, direct_rm, rtol=0.0, atol=1e-6)


def test_partial_plans_ignore_what_no_candidate_can_reach(cfg: CellConfig) -> None:
    """One sphere alone reaches 27 of 30 directions: weight along the other three changes
    neither the projected W nor the choice."""
    J = _blocks(cfg, "P2")
    d = detmax.column_scale(J)
    G = J * d
    P = observable_projector(np.einsum("kil,kim->lm", G, G))
    assert round(float(np.trace(P))) == 27
    null = np.linalg.eigh(np.eye(30) - P)[1][:, -3:]  # the unreachable directions (scaled)
    W = _weight()
    heavy = W + 1e6 * (null / d[:, None]) @ (null / d[:, None]).T  # W in unscaled units
    rng = np.random.default_rng(0)
    a = detmax.select(J, 6, rng, criterion="I", weight=W)
    b = detmax.select(J, 6, np.random.default_rng(0), criterion="I", weight=heavy)
    assert np.array_equal(a.indices, b.indices)
    assert a.log_value == pytest.approx(b.log_value, rel=1e-6)


def test_i_index_is_the_inverse_rms_of_the_predicted_error_in_any_units(cfg: CellConfig) -> None:
    J = np.concatenate([_blocks(cfg, n)[::50][:6] for n in cfg.spheres_part_mm])
    W = _weight()
    M = np.einsum("kil,kim->lm", J, J)
    expected = 1.0 / np.sqrt(np.trace(W @ np.linalg.inv(M)))
    assert i_index(J, W) == pytest.approx(expected, rel=1e-6)
    s = np.geomspace(1e-3, 1e3, 30)  # other units per parameter: J S, W -> S W S
    assert i_index(J * s, W * np.outer(s, s)) == pytest.approx(expected, rel=1e-6)
    assert plan_index(J, "I", weight=W) == pytest.approx(expected, rel=1e-6)
    assert i_index(J[:6], W) == 0.0  # one sphere: rank 27, nothing to say about all 30
    with pytest.raises(ValueError, match="workspace weight"):
        plan_index(J, "I")


def test_workspace_weight_is_the_mean_information_of_the_views() -> None:
    J = np.random.default_rng(1).normal(size=(7, 3, 5))
    W = workspace_weight(J)
    assert np.allclose(W, sum(j.T @ j for j in J) / 7)
    with pytest.raises(ValueError, match="no workspace views"):
        workspace_weight(np.zeros((0, 3, 5)))


def test_the_i_plan_predicts_a_smaller_workspace_error_than_the_o1_plan(cfg: CellConfig) -> None:
    """At the cell's sphere positions, configurations chosen with "I" and revisited (each
    sphere re-chosen given the others) give a smaller mean predicted error over the workspace
    (trace(W M^-1), W from another random stream than the planner's) than the paper's
    sequential O1 choice; O1 keeps the larger determinant."""
    model = cfg.model()
    x = model.nominal_x()
    W = weight_for(cfg, model, x, PAPER_30, seed=0)
    W_check = weight_for(cfg, model, x, PAPER_30, seed=1)
    out = {}
    for criterion, passes in (("O1", 0), ("I", 2)):
        s = PlanSettings(grid=GRID30, criterion=criterion, weight=W, revisits=passes)
        spheres, J = select_configurations(model, x, cfg.spheres_part_mm, s)
        if passes:
            _, J = revisit(model, x, spheres, s)
        M = np.einsum("kil,kim->lm", J, J)
        out[criterion] = (np.trace(W_check @ np.linalg.inv(M)), np.linalg.slogdet(M)[1])
    assert out["I"][0] < 0.95 * out["O1"][0]
    assert out["O1"][1] > out["I"][1]


def test_plan_overrides_and_run_plan_accept_the_workspace_criterion(cfg: CellConfig) -> None:
    class Args:
        criterion = "I"

    assert plan_overrides(Args())["criterion"] == "I"  # type: ignore[arg-type]
    model = cfg.model()
    x = model.nominal_x()
    result = run_plan(
        cfg, model, x, criterion="I", placement="fixed", grid_step_deg=30.0, workers=1
    )
    assert result.settings.weight is not None and result.settings.weight.shape == (30, 30)
    assert result.observability.rank == 30
