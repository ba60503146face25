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
from app.formats.files import write_json
from app.formats.report import markdown_table, text_table
from app.sim.cell import make_cell
from app.workspace import workspace_points
from calib import candidates
from calib.compliance import CompliantModel, CompliantSettings
from calib.identify import Measurements, identify, residuals
from calib.model import SystemModel
from calib.validation import rmse
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


#: (name, cell temperature range [degC]) of each scenario
SCENARIOS: tuple[tuple[str, tuple[float, float]], ...] = (
    ("warm-up", (20.0, 30.0)),
    ("constant temperature", (20.0, 20.0)),
)


@dataclass(frozen=True)
class AccuracySettings:
    n_each: int = 10
    n_validation: int = 100
    scenarios: tuple[tuple[str, tuple[float, float]], ...] = SCENARIOS
    compliant: CompliantSettings = field(default_factory=CompliantSettings)


LABELS = ("rigid", "compliant, no temp", "compliant", "noise floor")
VALUE_NAMES = ("c2_upper", "c2_fore", "c3_fore", "expansion_per_k")


@dataclass(frozen=True)
class AccuracyOutcome:
    seed: int
    scenario: str
    rmse_mm: dict[str, float]  # against the tracker
    rmse_truth_mm: dict[str, float]  # against the truth
    values: dict[str, float]  # identified compliance and expansion (compliant model)
    expansion_identified: bool
    seconds: dict[str, float]  # identification time per model


def _cells_and_data(
    cfg: CellConfig, seed: int, s: AccuracySettings, temp_range_c: tuple[float, float]
) -> tuple[dict[str, WarmData], dict[str, WarmData]]:
    """Calibration and validation data of the full and the floor cell, same views."""
    cells = {
        "full": make_cell(cfg, seed=seed),
        "floor": make_cell(cfg, seed=seed, compliance=False, thermal=False),
    }
    rigid = cfg.model()
    rng = np.random.default_rng([seed, 13])
    both = tuple(cells.values())
    views = plan_views(both, rigid, cfg.spheres_part_mm, s.n_each, temp_range_c, rng)
    val_points = workspace_points(cfg, s.n_validation, rng)
    val_views = plan_views(both, rigid, val_points, 1, temp_range_c, rng)
    data = {name: measure_views(c, views) for name, c in cells.items()}
    val = {name: measure_views(c, val_views) for name, c in cells.items()}
    return data, val


def run_seed(
    cfg: CellConfig, seed: int, s: AccuracySettings, scenario: tuple[str, tuple[float, float]]
) -> AccuracyOutcome:
    rigid = cfg.model()
    compliant = CompliantModel.of(rigid, s.compliant)
    data, val = _cells_and_data(cfg, seed, s, scenario[1])
    full, floor = data["full"].measured, data["floor"].measured
    cases = (
        ("rigid", rigid, without_temperature(full), "full"),
        ("compliant, no temp", compliant, without_temperature(full), "full"),
        ("compliant", compliant, full, "full"),
        ("noise floor", rigid, without_temperature(floor), "floor"),
    )
    rmse_by, rmse_truth, seconds = {}, {}, {}
    values: dict[str, float] = {}
    identified = False
    for label, model, m, cell_name in cases:
        t0 = time.perf_counter()
        result = identify(model, m)
        seconds[label] = time.perf_counter() - t0
        v = val[cell_name]
        keep = label == "compliant"  # the only one given the temperatures
        vm, vt = (v.measured, v.truth) if keep else map(without_temperature, (v.measured, v.truth))
        rmse_by[label] = rmse(residuals(model, result.x, vm))
        rmse_truth[label] = rmse(residuals(model, result.x, vt))
        if keep:
            values = {n: result.value(n) for n in VALUE_NAMES}
            identified = "expansion_per_k" in result.active
    return AccuracyOutcome(seed, scenario[0], rmse_by, rmse_truth, values, identified, seconds)


HEADER = ["model", "median RMSE mm", "ratio to floor", "median vs truth mm", "seeds within 15 %"]


def table_rows(outcomes: list[AccuracyOutcome]) -> list[list[str]]:
    rows = []
    f = np.array([o.rmse_mm["noise floor"] for o in outcomes])
    for label in LABELS:
        r = np.array([o.rmse_mm[label] for o in outcomes])
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
        if name == "expansion_per_k" and not all(o.expansion_identified for o in outcomes):
            continue
        v = np.array([o.values[name] for o in outcomes])
        q = np.percentile(v, [25, 75])
        rows.append([name, f"{true:.4g}", f"{np.median(v):.4g}", f"{q[0]:.4g} .. {q[1]:.4g}"])
    return rows


def simulated_truth() -> dict[str, float]:
    """The lumped coefficients of the simulated robot (fakes.truth's masses and compliance)."""
    from fakes.truth import GRAVITY_M_S2, LINK_MASS_KG, TrueRobot

    m_up, m_fore, m_tool = LINK_MASS_KG
    robot = TrueRobot.perturbed(np.random.default_rng(0))
    k2, k3 = robot.compliance_rad_per_nm
    g = GRAVITY_M_S2
    return {
        "c2_upper": k2 * g * (m_up / 2 + m_fore + m_tool),
        "c2_fore": k2 * g * (m_fore / 2 + m_tool),
        "c3_fore": k3 * g * (m_fore / 2 + m_tool),
        "expansion_per_k": robot.expansion_per_k,
    }


def run_accuracy(
    cfg: CellConfig,
    seeds: list[int],
    out_dir: Path,
    settings: AccuracySettings | None = None,
    log: Callable[[str], None] = print,
) -> list[AccuracyOutcome]:
    """Every scenario over every seed; writes accuracy.md and accuracy-seeds.json."""
    s = settings or AccuracySettings()
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    outcomes: list[AccuracyOutcome] = []
    for scenario in s.scenarios:
        for k, seed in enumerate(seeds):
            o = run_seed(cfg, seed, s, scenario)
            outcomes.append(o)
            r = o.rmse_mm
            log(
                f"{scenario[0]}, seed {seed} ({k + 1}/{len(seeds)}): RMSE rigid {r['rigid']:.4f},"
                f" compliant {r['compliant']:.4f}, floor {r['noise floor']:.4f} mm"
            )
            write_json(out_dir / "accuracy-seeds.json", {"seeds": [asdict(x) for x in outcomes]})
    write_markdown(outcomes, s, out_dir / "accuracy.md", time.perf_counter() - t0)
    return outcomes


def by_scenario(outcomes: list[AccuracyOutcome]) -> dict[str, list[AccuracyOutcome]]:
    out: dict[str, list[AccuracyOutcome]] = {}
    for o in outcomes:
        out.setdefault(o.scenario, []).append(o)
    return out


def summary_text(outcomes: list[AccuracyOutcome]) -> str:
    return "\n\n".join(
        f"{name}:\n{text_table(HEADER, table_rows(group))}"
        for name, group in by_scenario(outcomes).items()
    )


def write_markdown(
    outcomes: list[AccuracyOutcome], s: AccuracySettings, path: Path, seconds: float
) -> None:
    seeds = sorted({o.seed for o in outcomes})
    ranges = dict(s.scenarios)
    md = [
        "# Accuracy beyond the paper: the compliance- and temperature-aware model",
        f"Written by `rvis experiment accuracy` ({len(seeds)} seeds {seeds[0]}..{seeds[-1]}, "
        f"{seconds:.0f} s). Simulated cell with gravity compliance of J2/J3 and thermal growth; "
        f"{s.n_each} random views per sphere (4 spheres), {s.n_validation} validation "
        "positions (one random view each); every measurement at its own cell temperature, "
        f"uniform in the scenario's range (reference {s.compliant.reference_temp_c:g} degC). "
        "Noise floor: the same cell with compliance and thermal growth off (same robot, "
        "views, temperatures and sensor and tracker noise), rigid model. Goal: compliant "
        f"within {100 * (GOAL_RATIO - 1):.0f} % of the floor.",
        "RMSE against the simulated tracker (includes the validation measurements' own "
        "noise); ratio: median (min .. max) over seeds of RMSE / floor RMSE of the same seed; "
        "vs truth: noise-free validation centres (the identified parameters' error alone). "
        "Rows: rigid = the paper's 30; compliant, no temp = 30 + arm compliance, no "
        "temperature input; compliant = 30 + arm compliance + thermal term (expansion "
        "identified when the temperatures span >= "
        f"{s.compliant.min_temp_span_k:g} K), with the temperatures.",
    ]
    for name, group in by_scenario(outcomes).items():
        lo, hi = ranges[name]
        md += [
            f"## {name}: {lo:g}..{hi:g} degC",
            markdown_table(HEADER, table_rows(group)),
            "Identified coefficients (compliant model):",
            markdown_table(
                ["parameter", "simulated truth", "median", "quartiles"],
                value_rows(group, simulated_truth()),
            ),
        ]
    secs = {lbl: float(np.median([o.seconds[lbl] for o in outcomes])) for lbl in LABELS}
    md.append(
        "Median identification time: "
        + ", ".join(f"{lbl} {1e3 * t:.0f} ms" for lbl, t in secs.items())
        + " (shared, loaded machine)."
    )
    path.write_text("\n\n".join(md) + "\n", encoding="utf-8")
