"""Runs of the paper's experiment side by side (`rvis experiment paper-compare RUN...`).

Every run holds the same seeds' random pre-calibration and validation sets (they come
before the plan in each seed's random stream), so runs that differ only in the planning
compare seed by seed. Per run and model: the reduction random -> planned of the validation
RMSE (median with its bootstrap interval, quartiles, seeds better), the same against the
truth, and the paired change of the planned RMSE against the first run. The ceiling is the
reduction a perfect identification would give: the validation measurements' own noise
(sqrt(RMSE^2 - RMSE vs truth^2)) stays.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.errors import InputError
from app.formats.files import read_json

F64 = NDArray[np.float64]
HEADER = [
    "run",
    "model",
    "seeds",
    "RMSE random -> planned mm (median)",
    "reduction median",
    "90 % interval of the median",
    "quartiles",
    "seeds better",
    "vs truth median",
    "ceiling median",
    "planned vs first run (median, seeds lower)",
]
MODELS = (("rigid", ""), ("compliant", " (compliant)"))


def load_run(folder: Path) -> dict[int, dict[str, Any]]:
    """The seeds of a run folder's seeds.json, by seed."""
    data = read_json(folder / "seeds.json")
    try:
        return {int(d["seed"]): d for d in data["seeds"]}
    except (KeyError, TypeError) as exc:
        raise InputError(f"malformed seeds ({exc})", file=folder / "seeds.json") from None


def median_interval(values: F64, n_boot: int = 2000, level: float = 0.9) -> F64:
    """The bootstrap interval (percentile, seeded) of the median of `values`: how far the
    median of this many seeds may move with other seeds."""
    rng = np.random.default_rng(0)
    boot = np.median(rng.choice(values, size=(n_boot, values.size), replace=True), axis=1)
    out: F64 = np.percentile(boot, [50 * (1 - level), 50 * (1 + level)])
    return out


def _values(run: dict[int, dict[str, Any]], seeds: list[int], key: str, label: str) -> F64:
    return np.array([run[s][key][label] for s in seeds])


def compare_rows(runs: dict[str, dict[int, dict[str, Any]]]) -> list[list[str]]:
    """Table rows (HEADER) over the seeds that every run holds."""
    common = sorted(set.intersection(*(set(r) for r in runs.values())))
    if not common:
        raise InputError("the runs have no seed in common")
    first = next(iter(runs.values()))
    rows = []
    for model, suffix in MODELS:
        for name, run in runs.items():
            if "planned" + suffix not in run[common[0]]["rmse_mm"]:
                continue
            rows.append(_row(name, model, run, first, common, suffix))
    return rows


def _row(
    name: str,
    model: str,
    run: dict[int, dict[str, Any]],
    first: dict[int, dict[str, Any]],
    seeds: list[int],
    suffix: str,
) -> list[str]:
    r = _values(run, seeds, "rmse_mm", "random" + suffix)
    p = _values(run, seeds, "rmse_mm", "planned" + suffix)
    rt = _values(run, seeds, "rmse_truth_mm", "random" + suffix)
    pt = _values(run, seeds, "rmse_truth_mm", "planned" + suffix)
    red = 1.0 - p / r
    noise = np.sqrt(np.clip(r**2 - rt**2, 0.0, None))
    q = np.percentile(red, [25, 75])
    p0 = _values(first, seeds, "rmse_mm", "planned" + suffix)
    change = p / p0 - 1.0
    return [
        name,
        model,
        str(len(seeds)),
        f"{np.median(r):.4f} -> {np.median(p):.4f}",
        f"{100 * np.median(red):.1f} %",
        "{:.1f} .. {:.1f} %".format(*(100 * median_interval(red))),
        f"{100 * q[0]:.1f} .. {100 * q[1]:.1f} %",
        f"{int(np.sum(red > 0))}/{len(seeds)}",
        f"{100 * np.median(1.0 - pt / rt):.1f} %",
        f"{100 * np.median(1.0 - noise / r):.1f} %",
        f"{100 * np.median(change):+.1f} %, {int(np.sum(change < 0))}/{len(seeds)}",
    ]
