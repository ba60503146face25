"""`rvis experiment accuracy`: the rigid vs the compliance-aware model on the simulated cell,
against the noise floor, over many seeds.

Per seed: the simulated cell with its gravity compliance and thermal growth, measured while
the cell warms up (each measurement at its own temperature, uniform in `temp_range_c`), and
the same cell with compliance and thermal growth off (same robot errors, same views, same
temperatures, same sensor and tracker noise): the noise floor. On the full cell:

    rigid                  the paper's 30 parameters (temperatures not used)
    compliant, no temp     30 + arm compliance, the temperature column left out
    compliant              30 + arm compliance + expansion coefficient, with temperatures
    noise floor            the rigid model on the floor cell

Validation RMSE over `n_validation` positions (one random view each, at its own temperature):
against the simulated tracker, as the paper measures it, and against the truth (noise-free
centres: the identified parameters' error alone).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from app.config import CellConfig
from app.files import write_json
from app.report import markdown_table, text_table
from app.simulation import make_cell, validation_points
from calib import candidates
from calib.compliance import CompliantModel, CompliantSettings
from calib.identify import Measurements, identify, residuals
from calib.model import SystemModel
from fakes.cell import SimulatedCell

F64 = NDArray[np.float64]
#: the goal of issue 13: the compliant model within 15 % of the noise floor
GOAL_RATIO = 1.15


@dataclass(frozen=True)
class WarmData:
    """Measurements (with temp_c) and the same views' noise-free truth (true centres in the
    sensor frame, true sphere positions) as Measurements too."""

    measured: Measurements
    truth: Measurements


@dataclass(frozen=True)
class View:
    target: str
    q_deg: F64
    p_part_mm: F64
    temp_c: float


def plan_views(
    cells: Sequence[SimulatedCell],
    model: SystemModel,
    points_part_mm: Mapping[str, F64],
    n_each: int,
    temp_range_c: tuple[float, float],
    rng: np.random.Generator,
) -> list[View]:
    """n_each random views of each point that every cell sees, each at a random temperature."""
    x0 = model.nominal_x()
    views: list[View] = []
    for tid, p in points_part_mm.items():
        options = candidates.random_configurations(model, x0, p, 3 * n_each, rng).q_deg
        got = 0
        for q in options:
            t = float(rng.uniform(*temp_range_c))
            for cell in cells:
                cell.temp_c = t
            if got < n_each and all(cell.sees(q, p) for cell in cells):
                views.append(View(tid, q, p, t))
                got += 1
    return views


def measure_views(cell: SimulatedCell, views: list[View]) -> WarmData:
    """Measure every view at its temperature (tracker first: one centre per target)."""
    tracked = {v.target: cell.track_point(v.p_part_mm) for v in views}
    c, c_true = [], []
    for v in views:
        cell.temp_c = v.temp_c
        c_true.append(cell.centre_in_sensor(v.q_deg, v.p_part_mm)[0])
        c.append(cell.measure_point(v.q_deg, v.p_part_mm))
    q = np.array([v.q_deg for v in views])
    ids = tuple(v.target for v in views)
    temps = np.array([v.temp_c for v in views])
    measured = Measurements(q, np.array(c), np.array([tracked[t] for t in ids]), ids, temps)
    p_true = np.array([v.p_part_mm for v in views])
    return WarmData(measured, Measurements(q, np.array(c_true), p_true, ids, temps))


def without_temperature(m: Measurements) -> Measurements:
    return Measurements(m.q_deg, m.c_sensor_mm, m.p_part_mm, m.targets)


@dataclass(frozen=True)
class AccuracySettings:
    n_each: int = 10
    n_validation: int = 100
    temp_range_c: tuple[float, float] = (20.0, 30.0)
    compliant: CompliantSettings = field(default_factory=CompliantSettings)


LABELS = ("rigid", "compliant, no temp", "compliant", "noise floor")


@dataclass(frozen=True)
class AccuracyOutcome:
    seed: int
    rmse_mm: dict[str, float]  # against the tracker
    rmse_truth_mm: dict[str, float]  # against the truth
    values: dict[str, float]  # identified compliance and expansion (compliant model)
    seconds: dict[str, float]  # identification time per model


def _rmse(e: F64) -> float:
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


def run_seed(cfg: CellConfig, seed: int, s: AccuracySettings) -> AccuracyOutcome:
    rigid = cfg.model()
    compliant = CompliantModel.of(rigid, s.compliant)
    full = make_cell(cfg, seed=seed)
    floor = make_cell(cfg, seed=seed, compliance=False, thermal=False)
    rng = np.random.default_rng([seed, 13])
    views = plan_views((full, floor), rigid, cfg.spheres_part_mm, s.n_each, s.temp_range_c, rng)
    val_points = validation_points(cfg, s.n_validation, rng)
    val_views = plan_views((full, floor), rigid, val_points, 1, s.temp_range_c, rng)
    data = {name: measure_views(c, views) for name, c in (("full", full), ("floor", floor))}
    val = {name: measure_views(c, val_views) for name, c in (("full", full), ("floor", floor))}
    fits: dict[str, tuple[SystemModel, F64, str]] = {}
    seconds: dict[str, float] = {}
    cases = (
        ("rigid", rigid, without_temperature(data["full"].measured), "full"),
        ("compliant, no temp", compliant, without_temperature(data["full"].measured), "full"),
        ("compliant", compliant, data["full"].measured, "full"),
        ("noise floor", rigid, without_temperature(data["floor"].measured), "floor"),
    )
    for label, model, m, cell_name in cases:
        t0 = time.perf_counter()
        result = identify(model, m)
        seconds[label] = time.perf_counter() - t0
        fits[label] = (model, result.x, cell_name)
    rmse, rmse_truth = {}, {}
    for label, (model, x, cell_name) in fits.items():
        v = val[cell_name]
        uses_temp = label == "compliant"
        vm = v.measured if uses_temp else without_temperature(v.measured)
        vt = v.truth if uses_temp else without_temperature(v.truth)
        rmse[label] = _rmse(residuals(model, x, vm))
        rmse_truth[label] = _rmse(residuals(model, x, vt))
    x_c = fits["compliant"][1]
    names = ("c2_upper", "c2_fore", "c3_fore", "expansion_per_k")
    values = {n: float(x_c[compliant.names.index(n)]) for n in names}
    return AccuracyOutcome(seed, rmse, rmse_truth, values, seconds)


HEADER = ["model", "median RMSE mm", "ratio to floor", "median vs truth mm", "seeds within 15 %"]


def table_rows(outcomes: list[AccuracyOutcome]) -> list[list[str]]:
    rows = []
    for label in LABELS:
        r = np.array([o.rmse_mm[label] for o in outcomes])
        f = np.array([o.rmse_mm["noise floor"] for o in outcomes])
        t = np.array([o.rmse_truth_mm[label] for o in outcomes])
        ratio = r / f
        within = "-" if label == "noise floor" else f"{int(np.sum(ratio <= GOAL_RATIO))}/{r.size}"
        rows.append(
            [
                label,
                f"{np.median(r):.4f}",
                f"{np.median(ratio):.3f} ({ratio.min():.3f} .. {ratio.max():.3f})",
                f"{np.median(t):.4f}",
                within,
            ]
        )
    return rows


def value_rows(outcomes: list[AccuracyOutcome], truth: Mapping[str, float]) -> list[list[str]]:
    rows = []
    for name, true in truth.items():
        v = np.array([o.values[name] for o in outcomes])
        rows.append(
            [name, f"{true:.4g}", f"{np.median(v):.4g}", f"{100 * np.std(v) / abs(true):.1f} %"]
        )
    return rows


def simulated_truth() -> dict[str, float]:
    """The lumped coefficients of the simulated robot (fakes.truth's masses and compliance)."""
    from fakes.truth import GRAVITY_M_S2, LINK_MASS_KG, TrueRobot

    m_up, m_fore, m_tool = LINK_MASS_KG
    k2, k3 = TrueRobot.perturbed(np.random.default_rng(0)).compliance_rad_per_nm
    g = GRAVITY_M_S2
    return {
        "c2_upper": k2 * g * (m_up / 2 + m_fore + m_tool),
        "c2_fore": k2 * g * (m_fore / 2 + m_tool),
        "c3_fore": k3 * g * (m_fore / 2 + m_tool),
        "expansion_per_k": TrueRobot.perturbed(np.random.default_rng(0)).expansion_per_k,
    }


def run_accuracy(
    cfg: CellConfig,
    seeds: list[int],
    out_dir: Path,
    settings: AccuracySettings | None = None,
    log: Callable[[str], None] = print,
) -> list[AccuracyOutcome]:
    s = settings or AccuracySettings()
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    outcomes: list[AccuracyOutcome] = []
    for k, seed in enumerate(seeds):
        o = run_seed(cfg, seed, s)
        outcomes.append(o)
        r = o.rmse_mm
        log(
            f"seed {seed} ({k + 1}/{len(seeds)}): RMSE rigid {r['rigid']:.4f}, compliant "
            f"{r['compliant']:.4f}, floor {r['noise floor']:.4f} mm"
        )
        write_json(out_dir / "accuracy-seeds.json", {"seeds": [asdict(x) for x in outcomes]})
    write_markdown(outcomes, s, out_dir / "accuracy.md", time.perf_counter() - t0)
    return outcomes


def summary_text(outcomes: list[AccuracyOutcome]) -> str:
    return text_table(HEADER, table_rows(outcomes))


def write_markdown(
    outcomes: list[AccuracyOutcome], s: AccuracySettings, path: Path, seconds: float
) -> None:
    secs = {lbl: float(np.median([o.seconds[lbl] for o in outcomes])) for lbl in LABELS}
    md = [
        "# Accuracy beyond the paper: the compliance- and temperature-aware model",
        f"Written by `rvis experiment accuracy` ({len(outcomes)} seeds "
        f"{outcomes[0].seed}..{outcomes[-1].seed}, {seconds:.0f} s). Simulated cell with "
        f"gravity compliance of J2/J3 and thermal growth; {s.n_each} random views per sphere "
        f"(4 spheres), {s.n_validation} validation positions; every measurement at its own "
        f"cell temperature, uniform in {s.temp_range_c[0]:g}..{s.temp_range_c[1]:g} degC "
        f"(reference {s.compliant.reference_temp_c:g} degC). Noise floor: the same cell with "
        "compliance and thermal growth off (same robot, views, temperatures and noise), rigid "
        f"model. Goal: compliant within {100 * (GOAL_RATIO - 1):.0f} % of the floor.",
        markdown_table(HEADER, table_rows(outcomes)),
        "RMSE against the simulated tracker (includes the validation measurements' own "
        "noise); ratio: median (min .. max) over seeds of RMSE / floor RMSE of the same seed; "
        "vs truth: noise-free validation centres (the identified parameters' error alone).",
        "## Identified coefficients (compliant model)",
        markdown_table(
            ["parameter", "simulated truth", "median", "spread (std / truth)"],
            value_rows(outcomes, simulated_truth()),
        ),
        "Median identification time: "
        + ", ".join(f"{lbl} {1e3 * t:.0f} ms" for lbl, t in secs.items())
        + " (shared, loaded machine).",
    ]
    path.write_text("\n\n".join(md) + "\n", encoding="utf-8")
