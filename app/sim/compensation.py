"""Compensation on the simulated cell: does the true robot's pose error drop from the nominal
level to the calibrated level? (`rvis experiment compensation`, docs/results/compensation.md)

Per seed: a new simulated cell (its own robot errors, unmodelled J2/J3 compliance); calibration
as the line does it (4 spheres x 6 random configurations, identify); then n intended sensor
poses, realistic inspection views (each looks at a random point of the workspace from the
standoff, as the validation views do), given as joint targets taught on the nominal model. The
true robot (fakes.truth, not calib's model) is sent

- the original joints (what a nominal controller does today),
- the compensated joints (`calib.compensate`), and the same rounded to the 3 decimals of a
  FANUC `.ls` position,

and its true sensor pose is compared with the intended one: position of the sensor origin
(TCP), orientation, and the point at the standoff on the sensor axis (where the sensor
measures). "calibrated level": the identified model's own error against the truth at the same
joints (the best a compensation with these parameters can do).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from app.config import CellConfig
from app.formats.report import markdown_table
from app.sim.cell import collect, make_cell
from app.workspace import workspace_points
from calib import candidates
from calib.compensate import compensate_joints
from calib.identify import identify
from calib.transforms import apply

F64 = NDArray[np.float64]

CASES = ("nominal", "compensated", "compensated, .ls 3 decimals", "calibrated level")


@dataclass(frozen=True)
class PoseErrors:
    """Per pose: TCP position error [mm], orientation error [mrad], error of the point at the
    standoff [mm]."""

    position_mm: F64
    rotation_mrad: F64
    standoff_mm: F64

    @staticmethod
    def between(T: F64, T_ref: F64, standoff_mm: float) -> PoseErrors:
        dp = np.linalg.norm(T[:, :3, 3] - T_ref[:, :3, 3], axis=1)
        dR = np.swapaxes(T_ref[:, :3, :3], 1, 2) @ T[:, :3, :3]
        cos = np.clip((np.trace(dR, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
        c = np.array([0.0, 0.0, standoff_mm])
        ds = np.linalg.norm(apply(T, c) - apply(T_ref, c), axis=1)
        return PoseErrors(dp, 1000.0 * np.arccos(cos), ds)

    @staticmethod
    def concat(items: list[PoseErrors]) -> PoseErrors:
        return PoseErrors(
            *(np.concatenate([getattr(e, f) for e in items]) for f in PoseErrors.__annotations__)
        )


@dataclass(frozen=True)
class SeedResult:
    seed: int
    errors: dict[str, PoseErrors]
    n_poses: int
    n_refused: int
    calibration_rms_mm: float


def view_configurations(cfg: CellConfig, n: int, rng: np.random.Generator) -> F64:
    """n joint targets (n, 6) [deg]: each a random view of a random workspace point, planned
    on the nominal model."""
    model = cfg.model()
    x0 = model.nominal_x()
    out: list[F64] = []
    while len(out) < n:
        for p in workspace_points(cfg, n - len(out), rng).values():
            q = candidates.random_configurations(model, x0, p, 1, rng).q_deg
            out += list(q[:1])
    return np.array(out[:n])


def run_seed(cfg: CellConfig, seed: int, n_poses: int = 100) -> SeedResult:
    cell = make_cell(cfg, seed=seed)
    model = cfg.model()
    x0 = model.nominal_x()
    rng = np.random.default_rng([seed, 2])
    n_each = int(cfg.calibration["configs_per_sphere"])
    data = collect(cell, model, x0, cfg.spheres_part_mm, n_each, rng)
    result = identify(model, data.measurements, loss=str(cfg.calibration["loss"]))
    q_nom = view_configurations(cfg, n_poses, np.random.default_rng([seed, 5]))
    comp = compensate_joints(model, result.x, q_nom)
    ok = comp.ok
    T_int = comp.T_intended[ok]
    standoff = float(cfg.sensor["standoff_mm"])
    q_c = comp.q_deg[ok]
    sent = {
        "nominal": cell.T_part_sensor(q_nom[ok]),
        "compensated": cell.T_part_sensor(q_c),
        "compensated, .ls 3 decimals": cell.T_part_sensor(np.round(q_c, 3)),
    }
    errors = {k: PoseErrors.between(T, T_int, standoff) for k, T in sent.items()}
    T_true = cell.T_part_sensor(q_nom[ok])
    errors["calibrated level"] = PoseErrors.between(model.fk(result.x, q_nom[ok]), T_true, standoff)
    return SeedResult(seed, errors, n_poses, int((~ok).sum()), result.rms_mm)


def run(
    cfg: CellConfig, seeds: list[int], n_poses: int, log: Callable[[str], None] | None = None
) -> list[SeedResult]:
    out = []
    for seed in seeds:
        r = run_seed(cfg, seed, n_poses)
        if log:
            rms = np.sqrt(np.mean(r.errors["compensated"].position_mm ** 2))
            nom = np.sqrt(np.mean(r.errors["nominal"].position_mm ** 2))
            log(f"seed {seed}: TCP RMS nominal {nom:.3f} mm, compensated {rms:.3f} mm")
        out.append(r)
    return out


def _rms(v: F64) -> float:
    return float(np.sqrt(np.mean(v**2)))


def _stats_row(name: str, e: PoseErrors) -> list[str]:
    rms = _rms
    p = e.position_mm
    return [
        name,
        f"{np.mean(p):.3f}",
        f"{rms(p):.3f}",
        f"{np.percentile(p, 95):.3f}",
        f"{p.max():.3f}",
        f"{rms(e.rotation_mrad):.3f}",
        f"{e.rotation_mrad.max():.3f}",
        f"{rms(e.standoff_mm):.3f}",
        f"{e.standoff_mm.max():.3f}",
    ]


HEADER = ["sent to the true robot", "TCP mean", "TCP RMS", "TCP p95", "TCP max",
          "rot RMS [mrad]", "rot max [mrad]", "standoff pt RMS", "standoff pt max"]  # fmt: skip


SEED_HEADER = ["seed", "calibration residual RMS", "poses", "TCP nominal", "TCP compensated",
               "standoff pt nominal", "standoff pt compensated"]  # fmt: skip


def markdown(results: list[SeedResult], command: str) -> str:
    first = results[0]
    pooled = {k: PoseErrors.concat([r.errors[k] for r in results]) for k in CASES}
    per_seed = [
        [str(r.seed), f"{r.calibration_rms_mm:.3f}", str(r.n_poses - r.n_refused)]
        + [f"{_rms(r.errors[k].position_mm):.3f}" for k in CASES[:2]]
        + [f"{_rms(r.errors[k].standoff_mm):.3f}" for k in CASES[:2]]
        for r in results
    ]
    n_pooled = sum(r.n_poses - r.n_refused for r in results)
    lines = [
        "# Compensation on the simulated cell",
        "",
        f"Produced by `{command}` (app/sim/compensation.py). Intended sensor poses: joint",
        "targets planned on the nominal model (random views of random workspace points); the",
        "true robot of the simulated cell (with unmodelled J2/J3 compliance) is sent the",
        "original joints, the compensated joints, and the compensated joints rounded to the 3",
        "decimals of a FANUC `.ls` position. Errors of its true sensor pose against the",
        "intended one: TCP = sensor origin, standoff pt = the point 130 mm along the sensor",
        "axis (where it measures). Calibrated level: the identified model against the truth at",
        "the same joints. Lengths in mm.",
        "",
        f"## Seed {first.seed}: {first.n_poses - first.n_refused} poses"
        + (f" ({first.n_refused} refused by the compensation)" if first.n_refused else ""),
        "",
        markdown_table(HEADER, [_stats_row(k, first.errors[k]) for k in CASES]),
        "",
        f"## All {len(results)} seeds pooled: {n_pooled} poses",
        "",
        markdown_table(HEADER, [_stats_row(k, pooled[k]) for k in CASES]),
        "",
        "## Per seed: RMS [mm]",
        "",
        markdown_table(SEED_HEADER, per_seed),
        "",
        "## Reading it",
        "",
        "- Compensation brings the true robot to the calibrated level: the compensated rows",
        "  equal the identified model's own error, so the compensation itself adds nothing",
        "  (inverse kinematics on the identified model converges to < 1e-6 mm). Rounding the",
        "  joints to 3 decimals for the `.ls` file changes the errors by a few micrometres.",
        "- The point where the sensor measures (standoff) drops to a few hundredths of a mm;",
        "  the sensor origin (TCP) and orientation much less. The calibration sees the sensor",
        "  only through sphere centres near the standoff (27 x 37 x 10 mm volume at 130 mm):",
        "  a tilt of the identified sensor frame and a shift of its origin that cancel at the",
        "  standoff are barely observable, so the TCP 130 mm behind it carries the tilt times",
        "  130 mm. For the inspection (measurements at the standoff) the standoff columns are",
        "  the relevant ones; a tool whose point is elsewhere needs its own calibration.",
        "- What remains at the standoff: the unmodelled J2/J3 gravity compliance of the",
        "  simulated robot and the calibration's own uncertainty (24 noisy sphere",
        "  measurements). With the compliance switched off (checked once, seeds 0-4, by",
        "  calling `run_seed` on a cell made with `compliance=False`) the compensated standoff",
        "  RMS was 0.025-0.039 mm per seed instead of 0.047-0.063 mm.",
        "",
    ]
    return "\n".join(lines)
