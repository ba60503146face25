"""The paper's experiment on the simulated cell, over many seeds (paper section 5).

Per seed: a new simulated cell (its own robot errors and noise); pre-calibration with 6 random
configurations at each Table 1 position; the plan on the pre-calibrated parameters (positions
by PSO, configurations by DETMAX); calibration with the planned configurations at the planned
positions; both validated on the same 100 positions. Then, at the planned positions, each of
O1..O5 as the DETMAX criterion and a random selection, to rank the indices by the validation
RMSE they give (the question Joubair and Bonev answered for serial robots: O1).

Validation RMSE is reported twice: against the simulated tracker (what the paper measures, it
includes the validation measurements' own noise) and against the truth (the identified
parameters' error alone).
"""

from __future__ import annotations

import itertools
import json
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.config import CellConfig
from app.errors import InputError
from app.formats.files import dumps_json, read_json, write_json, write_text
from app.formats.report import markdown_table, save_figure, text_table
from app.meta import provenance
from app.planning import plan_settings, run_plan
from app.sim.cell import DataSet, collect, simulated_sets
from app.sim.demo import truth_set
from calib.compliance import select_model
from calib.configurations import select_configurations
from calib.identify import identify, residuals
from calib.model import SystemModel
from calib.observability import INDEX_NAMES
from calib.transforms import apply, inverse
from calib.validation import rmse

F64 = NDArray[np.float64]
PAPER_O1 = (0.0472, 0.086)
PAPER_RMSE_REDUCTION = 0.186


@dataclass(frozen=True)
class SeedOutcome:
    seed: int
    o1: dict[str, float]  # random (Table 1), planned, and per criterion at planned positions
    rmse_mm: dict[str, float]  # against the tracker
    rmse_truth_mm: dict[str, float]  # parameters alone, against the truth
    n_measurements: dict[str, int]
    plan_seconds: float
    positions_base_mm: dict[str, list[float]]
    errors_mm: dict[str, list[float]]  # Euclidean validation error per position
    seconds: float = 0.0  # the seed's wall time


def run_seed(
    cfg: CellConfig,
    seed: int,
    n_validation: int = 100,
    criteria: bool = True,
    progress: Callable[[str, int, int, float], None] | None = None,
    criteria_grid_step_deg: float | None = None,
    compliant: bool = False,
    plan_model: str = "rigid",
    **plan_overrides: Any,
) -> SeedOutcome:
    """One seed. With `compliant`, every run is also identified and validated with the
    compliant model (labels "<run> (compliant)"). The plan is made for `plan_model`: the
    rigid pre-calibration's 30 parameters, or ("compliant") the compliant model's
    pre-calibration on the same random data and its parameters with the arm compliance."""
    t0 = time.perf_counter()
    sim = simulated_sets(cfg, seed, n_validation=n_validation)
    cell, model, rng, pre_data, val = sim.cell, sim.model, sim.rng, sim.calibration, sim.validation
    n_each = cfg.calibration.configs_per_sphere
    val_truth = truth_set(val, val.truth_c_sensor_mm, with_noise=False)
    loss = str(cfg.calibration["loss"])
    runs: dict[str, DataSet] = {"random": pre_data}
    pre = identify(model, pre_data.measurements, loss=loss)
    plan_fit = select_model(plan_model, model)
    x_plan = pre.x if plan_model == "rigid" else identify(plan_fit, pre_data.measurements).x
    plan = run_plan(cfg, plan_fit, x_plan, progress=progress, seed=seed, **plan_overrides)
    positions = plan.positions_part_mm()
    runs["planned"] = collect(
        cell, model, pre.x, positions, n_each, rng, q_by_target=plan.q_by_sphere()
    )
    if criteria:
        step = {} if criteria_grid_step_deg is None else {"grid_step_deg": criteria_grid_step_deg}
        settings, _ = plan_settings(cfg, seed=seed, **{**plan_overrides, **step})
        for name in INDEX_NAMES:
            s = replace(settings, criterion=name)
            spheres, _ = select_configurations(model, pre.x, positions, s)
            q_by = {sp.name: sp.q_deg for sp in spheres}
            runs[name] = collect(cell, model, pre.x, positions, n_each, rng, q_by_target=q_by)
        runs["random at planned positions"] = collect(cell, model, pre.x, positions, n_each, rng)
    o1, rmse_by, rmse_truth, counts, errors = {}, {}, {}, {}, {}
    fits = [("", model)] + ([(" (compliant)", select_model("compliant", model))] * compliant)
    for (suffix, fit), (run, data) in itertools.product(fits, runs.items()):
        label = run + suffix
        same = run == "random" and fit is model
        res = pre if same else identify(fit, data.measurements, loss=loss)
        e = residuals(fit, res.x, val.measurements)
        o1[label] = res.observability.indices["O1"]
        rmse_by[label] = rmse(e)
        rmse_truth[label] = rmse(residuals(fit, res.x, val_truth))
        counts[label] = len(data.measurements)
        errors[label] = np.linalg.norm(e, axis=1).tolist()
    base = _base_positions(model, pre.x, positions)
    seconds = time.perf_counter() - t0
    return SeedOutcome(
        seed, o1, rmse_by, rmse_truth, counts, plan.seconds["total"], base, errors, seconds
    )


def _base_positions(
    model: SystemModel, x: F64, positions: dict[str, F64]
) -> dict[str, list[float]]:
    T_base_part = inverse(model.T_part_base(x))
    return {k: apply(T_base_part, p).round(1).tolist() for k, p in positions.items()}


@dataclass(frozen=True)
class ExperimentSummary:
    outcomes: list[SeedOutcome]
    seconds: float  # wall time of this run (seeds taken from a resumed file cost nothing)
    load_1min: tuple[float, float] = (float("nan"), float("nan"))  # min, max over the run

    def reductions(self, key: str = "rmse_mm", label: str = "planned", base: str = "random") -> F64:
        vals = [getattr(o, key) for o in self.outcomes]
        return np.array([1.0 - v[label] / v[base] for v in vals])

    def table_rows(self) -> list[list[str]]:
        o1_r = np.median([o.o1["random"] for o in self.outcomes])
        o1_p = np.median([o.o1["planned"] for o in self.outcomes])
        red = self.reductions()
        red_t = self.reductions("rmse_truth_mm")
        q = np.percentile(red, [25, 75])
        return [
            ["O1, random configurations (Table 1)", f"{PAPER_O1[0]:.4f}", f"{o1_r:.4f}"],
            ["O1, planned", f"{PAPER_O1[1]:.4f}", f"{o1_p:.4f}"],
            ["O1 ratio planned / random", f"{PAPER_O1[1] / PAPER_O1[0]:.2f}", f"{o1_p / o1_r:.2f}"],
            [
                "validation RMSE reduction, median",
                f"{100 * PAPER_RMSE_REDUCTION:.1f} %",
                f"{100 * np.median(red):.1f} %",
            ],
            ["  quartiles", "-", f"{100 * q[0]:.1f} % .. {100 * q[1]:.1f} %"],
            ["  min .. max", "-", f"{100 * red.min():.1f} % .. {100 * red.max():.1f} %"],
            ["  seeds where planned is better", "-", f"{int(np.sum(red > 0))}/{red.size}"],
            ["RMSE reduction vs truth, median", "-", f"{100 * np.median(red_t):.1f} %"],
            [
                "validation RMSE random -> planned, median",
                "-",
                f"{np.median([o.rmse_mm['random'] for o in self.outcomes]):.4f} -> "
                f"{np.median([o.rmse_mm['planned'] for o in self.outcomes]):.4f} mm",
            ],
        ]

    def compliant_rows(self) -> list[list[str]]:
        """Random vs planned with the rigid and the compliant model (same data)."""
        if "planned (compliant)" not in self.outcomes[0].rmse_mm:
            return []
        rows = []
        for suffix, name in (("", "rigid"), (" (compliant)", "compliant")):
            r = np.array([o.rmse_mm["random" + suffix] for o in self.outcomes])
            p = np.array([o.rmse_mm["planned" + suffix] for o in self.outcomes])
            red = 1.0 - p / r
            red_t = self.reductions("rmse_truth_mm", "planned" + suffix, "random" + suffix)
            q = np.percentile(red, [25, 75])
            rows.append(
                [
                    name,
                    f"{np.median(r):.4f} -> {np.median(p):.4f}",
                    f"{100 * np.median(red):.1f} %",
                    f"{100 * q[0]:.1f} % .. {100 * q[1]:.1f} %",
                    f"{int(np.sum(red > 0))}/{red.size}",
                    f"{100 * np.median(red_t):.1f} %",
                ]
            )
        return rows

    def criteria_rows(self) -> list[list[str]]:
        labels = [*INDEX_NAMES, "random at planned positions"]
        if not all(lbl in self.outcomes[0].rmse_mm for lbl in labels):
            return []
        rmse = np.array([[o.rmse_mm[lbl] for lbl in labels] for o in self.outcomes])
        truth = np.array([[o.rmse_truth_mm[lbl] for lbl in labels] for o in self.outcomes])
        ranks = np.argsort(np.argsort(rmse, axis=1), axis=1) + 1
        order = np.argsort(np.median(rmse, axis=0))
        return [
            [
                labels[k],
                f"{np.median(rmse[:, k]):.4f}",
                f"{np.median(truth[:, k]):.4f}",
                f"{np.mean(ranks[:, k]):.2f}",
                str(int(np.sum(ranks[:, k] == 1))),
            ]
            for k in order
        ]


TABLE_HEADER = ["", "paper", "rvis (simulated)"]
COMPLIANT_HEADER = [
    "model",
    "median RMSE random -> planned mm",
    "median reduction",
    "quartiles",
    "seeds better",
    "reduction vs truth",
]
CRITERIA_HEADER = ["criterion", "median RMSE mm", "median vs truth mm", "mean rank", "wins"]


def run_experiment(
    cfg: CellConfig,
    seeds: list[int],
    out_dir: Path,
    *,
    n_validation: int = 100,
    criteria: bool = True,
    criteria_grid_step_deg: float | None = None,
    log: Callable[[str], None] = print,
    compliant: bool = False,
    plan_model: str = "rigid",
    resume: bool = False,
    **plan_overrides: Any,
) -> ExperimentSummary:
    """The experiment over `seeds`; `seeds.json` in out_dir is rewritten after every seed.
    With `resume`, the seeds it already holds are taken from it (InputError when it was
    written with other settings) and only the others are run."""
    t0 = time.perf_counter()
    out_dir.mkdir(parents=True, exist_ok=True)
    settings = {
        "cell": cfg.source,
        "n_validation": n_validation,
        "criteria": criteria,
        "criteria_grid_step_deg": criteria_grid_step_deg,
        "compliant": compliant,
        "plan_model": plan_model,
        "plan_overrides": plan_overrides,
    }
    done = _load_done(out_dir / "seeds.json", settings) if resume else {}
    load = [os.getloadavg()[0]]
    outcomes: list[SeedOutcome] = []
    for k, seed in enumerate(seeds):
        if seed in done:
            outcomes.append(done[seed])
            log(f"seed {seed} ({k + 1}/{len(seeds)}): from {out_dir / 'seeds.json'}")
            continue
        o = run_seed(
            cfg,
            seed,
            n_validation,
            criteria,
            criteria_grid_step_deg=criteria_grid_step_deg,
            compliant=compliant,
            plan_model=plan_model,
            **plan_overrides,
        )
        outcomes.append(o)
        load.append(os.getloadavg()[0])
        log(
            f"seed {seed} ({k + 1}/{len(seeds)}): O1 {o.o1['random']:.4f} -> {o.o1['planned']:.4f}"
            f", RMSE {o.rmse_mm['random']:.4f} -> {o.rmse_mm['planned']:.4f} mm "
            f"({100 * (o.rmse_mm['planned'] / o.rmse_mm['random'] - 1):+.1f} %), "
            f"{o.seconds:.0f} s"
        )
        write_json(
            out_dir / "seeds.json",
            {
                "provenance": provenance(),
                "settings": settings,
                "seeds": [asdict(x) for x in sorted(outcomes, key=lambda x: x.seed)],
            },
        )
    summary = ExperimentSummary(outcomes, time.perf_counter() - t0, (min(load), max(load)))
    _write(summary, out_dir, settings)
    return summary


def _load_done(path: Path, settings: dict[str, Any]) -> dict[int, SeedOutcome]:
    """The outcomes already in a seeds.json written with the same settings, by seed."""
    if not path.exists():
        return {}
    data = read_json(path)
    if data.get("settings") != json.loads(dumps_json(settings)):
        raise InputError(
            f"written with other settings ({data.get('settings')}); use another --out",
            file=path,
            field="settings",
        )
    try:
        return {int(d["seed"]): SeedOutcome(**d) for d in data["seeds"]}
    except (KeyError, TypeError) as exc:
        raise InputError(f"malformed seed entry ({exc})", file=path, field="seeds") from None


def summary_text(summary: ExperimentSummary) -> str:
    parts = [text_table(TABLE_HEADER, summary.table_rows())]
    if summary.compliant_rows():
        parts += [
            "Random vs planned, rigid and compliant model (same data):",
            text_table(COMPLIANT_HEADER, summary.compliant_rows()),
        ]
    rows = summary.criteria_rows()
    if rows:
        parts += [
            "Selection criteria at the planned positions (ranked by median validation RMSE):",
            text_table(CRITERIA_HEADER, rows),
        ]
    return "\n\n".join(parts)


def _write(summary: ExperimentSummary, out_dir: Path, settings: dict[str, Any]) -> None:
    meta = provenance()
    seeds = sorted(o.seed for o in summary.outcomes)
    cpu = sum(o.seconds for o in summary.outcomes)
    md = [
        "# The paper's experiment on the simulated cell",
        f"rvis {meta['rvis_version']} ({meta['git_commit'] or 'no git checkout'}); "
        f"{meta['utc_time']}; `{meta['command_line']}`",
        f"{len(seeds)} seeds ({_seed_list(seeds)}); settings {settings}; "
        f"{cpu:.0f} s over the seeds; 1-minute load average "
        f"{summary.load_1min[0]:.1f}..{summary.load_1min[1]:.1f} on {os.cpu_count()} cores.",
        markdown_table(TABLE_HEADER, summary.table_rows()),
    ]
    if summary.compliant_rows():
        md += [
            f"## Rigid and compliant model (the same data; the plan is made for the "
            f"{settings.get('plan_model', 'rigid')} model)",
            markdown_table(COMPLIANT_HEADER, summary.compliant_rows()),
        ]
    rows = summary.criteria_rows()
    if rows:
        md += ["## Selection criteria", markdown_table(CRITERIA_HEADER, rows)]
    md.append("![validation errors](fig11.png)")
    write_text(out_dir / "experiment.md", "\n\n".join(md) + "\n")
    plot_fig11(summary, out_dir / "fig11.png")


def _seed_list(seeds: list[int]) -> str:
    """ "0..19" for a run of consecutive seeds, else the list."""
    if seeds and seeds == list(range(seeds[0], seeds[-1] + 1)):
        return f"{seeds[0]}..{seeds[-1]}"
    return ", ".join(map(str, seeds))


def plot_fig11(summary: ExperimentSummary, path: Path) -> None:
    """Like the paper's Fig. 11: the Euclidean validation error per position, random vs
    planned, for the median seed; beside it the RMSE of every seed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    red = summary.reductions()
    median_seed = summary.outcomes[int(np.argsort(red)[len(red) // 2])]
    fig, (ax, bx) = plt.subplots(
        1, 2, figsize=(12, 4.5), dpi=110, gridspec_kw={"width_ratios": [2.2, 1]}
    )
    for label, style in (("random", "o-"), ("planned", "s-")):
        e = np.array(median_seed.errors_mm[label])
        ax.plot(
            np.arange(1, e.size + 1),
            e,
            style,
            ms=3,
            lw=1,
            label=f"{label} configurations (RMSE {np.sqrt(np.mean(e**2)):.3f} mm)",
        )
    ax.set_xlabel("validation position")
    ax.set_ylabel("Euclidean error [mm]")
    ax.set_title(f"seed {median_seed.seed} (median improvement)")
    ax.legend()
    ax.grid(True, alpha=0.3)
    r = np.array([[o.rmse_mm["random"], o.rmse_mm["planned"]] for o in summary.outcomes])
    for row in r:
        bx.plot([0, 1], row, "-", color="0.7", lw=0.8)
    bx.boxplot([r[:, 0], r[:, 1]], positions=[0, 1], widths=0.35)
    bx.set_xticks([0, 1], ["random", "planned"])
    bx.set_ylabel("validation RMSE [mm]")
    bx.set_title(f"{len(r)} seeds: median {100 * np.median(red):.1f} % lower")
    bx.grid(True, alpha=0.3)
    fig.tight_layout()
    save_figure(fig, path)
