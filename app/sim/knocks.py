"""The knock campaign of `rvis experiment shift --seeds N --knock ...`: the compressed shift over
many seeds per knock kind, and what the must-show asks of it: windows from the knock until the
true error is back within `recovered_ratio` x its pre-knock level (median, worst), the knock
flagged, no step alarm before the knock, 0 overruns, and the suspect intervals against the truth
(every window above the ratio covered; the share covered that was not). Written as
`shift-knocks.md`, `.json` and `.png`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from app.sim.shift_report import plot_shift, time_text, write_report_files
from app.sim.shift_result import ShiftResult
from app.sim.shift_score import scored_from_json


def _median(values: Sequence[float | int | None]) -> float | None:
    finite = [float(v) for v in values if v is not None]
    return float(np.median(finite)) if finite else None


def kind_row(kind: str, runs: Sequence[ShiftResult]) -> dict[str, Any]:
    """One knock kind over its seeds (and, in a campaign over several knock hours, one hour or
    all of them)."""
    rec = [r.recovered_after for r in runs]
    scores = [r.suspect_score for r in runs]
    sc = [s for s in scores if s is not None]
    k = [r.knock_window or 10**9 for r in runs]
    false_steps = sum(
        len([w for w in r.step_alarm_windows if w < kw]) for r, kw in zip(runs, k, strict=True)
    )
    episode_bad = sum(len(s.episode_bad) for s in sc)
    covered_all = sum(len(s.covered) + len(s.covered_before_knock) for s in sc)
    extra = sum(s.extra for s in sc)
    return {
        "knock": kind,
        "knock_at_h": sorted({r.settings.knock_at_h for r in runs}),
        "seeds": [r.seed for r in runs],
        "recovered_after": rec,
        "recovered_median": _median(rec),
        "recovered_max": None if None in rec else max(int(v) for v in rec if v is not None),
        "never_recovered": sum(v is None for v in rec),
        "flagged_after": [r.flagged_after for r in runs],
        "attribution": [r.attribution for r in runs],
        "attributed_right": sum(r.attribution == _GROUP[kind] for r in runs),
        "false_step_alarms_before_knock": false_steps,
        "overruns": sum(r.summary.overruns for r in runs),
        "recall_min": min((s.recall for s in sc), default=None),
        "bad_windows": sum(len(s.bad) for s in sc),
        "covered_windows": sum(len(s.covered) for s in sc),
        "extra_windows": extra,
        "extra_share": extra / covered_all if covered_all else 0.0,
        "episode_recall_min": min((s.episode_recall for s in sc), default=None),
        "episode_recall": (
            sum(len(s.episode_covered) for s in sc) / episode_bad if episode_bad else 1.0
        ),
        "episode_bad_windows": episode_bad,
        "episode_covered_windows": sum(len(s.episode_covered) for s in sc),
        "pre_knock_median_mm": _median([r.pre_knock_rmse_mm for r in runs]),
        "mean_rmse_mm": float(np.mean([np.mean([x.rmse_mm for x in r.records]) for r in runs])),
        "real_s": float(sum(r.real_s for r in runs)),
    }


def run_row(result: ShiftResult, command: str | None = None) -> dict[str, Any]:
    """One shift of a campaign: its seed, kind, hour and figures (and the command that runs it
    alone)."""
    sc = result.suspect_score
    k = result.knock_window or 10**9
    return {
        "knock": result.settings.knock,
        "knock_at_h": result.settings.knock_at_h,
        "hours": result.settings.hours,
        "seed": result.seed,
        "knock_window": result.knock_window,
        "recovered_after": result.recovered_after,
        "flagged_after": result.flagged_after,
        "attribution": result.attribution,
        "false_step_alarms_before_knock": len([w for w in result.step_alarm_windows if w < k]),
        "overruns": result.summary.overruns,
        "episode_end": None if sc is None else sc.episode_end,
        "episode_bad_windows": None if sc is None else len(sc.episode_bad),
        "episode_covered_windows": None if sc is None else len(sc.episode_covered),
        "episode_recall": None if sc is None else sc.episode_recall,
        "recall": None if sc is None else sc.recall,
        "extra_windows": None if sc is None else sc.extra,
        "extra_share": None if sc is None else sc.extra_share,
        "pre_knock_rmse_mm": result.pre_knock_rmse_mm,
        "mean_rmse_mm": float(np.mean([x.rmse_mm for x in result.records])),
        "real_s": result.real_s,
        "command": command,
    }


_GROUP = {"sensor": "sensor", "fixture": "fixture", "joint": "J2"}


def by_hour(runs: Sequence[ShiftResult]) -> dict[float, list[ShiftResult]]:
    """A kind's runs per knock hour, in the order of the hours."""
    out: dict[float, list[ShiftResult]] = {}
    for r in sorted(runs, key=lambda r: r.settings.knock_at_h):
        out.setdefault(r.settings.knock_at_h, []).append(r)
    return out


def _hours(results: Mapping[str, Sequence[ShiftResult]]) -> list[float]:
    return sorted({r.settings.knock_at_h for runs in results.values() for r in runs})


def _pct(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.0f} %"


def campaign_markdown(
    results: Mapping[str, Sequence[ShiftResult]],
    command: str,
    commands: Sequence[str] = (),
) -> str:
    """The campaign's table: a row per knock kind (several knock hours: per kind and hour,
    and a line per kind over all of them)."""
    first = next(r for runs in results.values() for r in runs)
    s = first.settings
    hours = _hours(results)
    several = len(hours) > 1
    if several:
        lengths = sorted(
            {r.settings.hours - r.settings.knock_at_h for rs in results.values() for r in rs}
        )
        when = f"knocks at {', '.join(f'{h:g}' for h in hours)} h, each shift running" + (
            f" {lengths[0]:g} h past its knock"
            if max(lengths) - min(lengths) < 1e-6
            else f" to {first.settings.hours:g} h"
        )
    else:
        when = f"{s.hours:g} h shifts with the warm-up, the knock at {s.knock_at_h:g} h"
    lines = [
        "# Knocks of three kinds over many seeds: windows to recover, suspect intervals",
        "",
        f"Generated by `{command}` ({when}; {time_text(first.scale)}; geometric measurements; the"
        f" cell file's estimator and model unless the command says otherwise). A window is"
        f" *back* when the"
        f" true RMS error at the line's validation positions with the parameters in force in it"
        f" is within {s.recovered_ratio:g}x the median of the {s.pre_knock_windows} windows"
        " before the knock; it is *covered* when it opened inside a suspect interval (the"
        " parameters in force in it were the suspect ones); *extra* windows are covered but"
        " were not above the ratio (or came before the knock). A window above the ratio is"
        " *caused by the knock* when its error is also above the ratio x the error the same"
        " seed had in that window without the knock (the counterfactual: each seed's longest"
        " shift run once more with a knock of size 0, in `without-knock/`; the warm-up's drift"
        " between two recalibrations puts the rigid model above 1.2x of a level measured 10"
        " windows earlier whether or not there was a knock). The knock's *episode* runs from"
        f" the knock to the last window it caused before {s.episode_gap_windows} windows in a"
        " row it did not; its recall is the share of the windows it caused that were covered"
        " (min over the seeds / all the seeds' windows together). The recall to the end of the"
        " shift counts every window above the ratio after the knock.",
        "",
        "| knock |"
        + (" knock at [h] |" if several else "")
        + " seeds | windows to recover: median / worst (target <= 3 / <= 6) | per seed"
        " | attributed right | step alarms before the knock | overruns | recall over the"
        " knock's episode: min / all (target >= 95 %) | episode windows above 1.2x / covered |"
        " extra windows (share of the covered; target <= 10 %) | recall to the end of the"
        " shift (min) | mean true error [mm] | pre-knock level (median) [mm] |",
        "|---|"
        + ("---:|" if several else "")
        + "---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for kind, runs in results.items():
        groups: list[tuple[str, Sequence[ShiftResult]]] = (
            [(f"{h:g}", rs) for h, rs in by_hour(runs).items()] + [("**all**", runs)]
            if several
            else [("", runs)]
        )
        for hour, group in groups:
            lines.append(_table_row(kind, hour if several else None, group))
    lines += ["", "![windows to recover and the error around the knock](shift-knocks.png)", ""]
    if commands:
        lines += [
            "To run one shift of the campaign alone (every run's command is in"
            " `shift-knocks.json`, `per_run`), e.g. the first:",
            "",
            "```",
            commands[0],
            "```",
            "",
        ]
    return "\n".join(lines)


def _table_row(kind: str, hour: str | None, runs: Sequence[ShiftResult]) -> str:
    r = kind_row(kind, runs)
    per_seed = " ".join("-" if v is None else str(v) for v in r["recovered_after"])
    return (
        f"| {kind} |"
        + ("" if hour is None else f" {hour} |")
        + f" {len(runs)} | {_n(r['recovered_median'])} / {_n(r['recovered_max'])}"
        f" | {per_seed} | {r['attributed_right']} of {len(runs)} |"
        f" {r['false_step_alarms_before_knock']} | {r['overruns']} |"
        f" {_pct(r['episode_recall_min'])} / {_pct(r['episode_recall'])} |"
        f" {r['episode_bad_windows']} / {r['episode_covered_windows']} |"
        f" {r['extra_windows']} ({_pct(r['extra_share'])}) | {_pct(r['recall_min'])} |"
        f" {r['mean_rmse_mm']:.4f} | {_n(r['pre_knock_median_mm'], 4)} |"
    )


def _n(value: float | int | None, digits: int = 0) -> str:
    if value is None:
        return "never"
    return f"{value:.{digits}f}" if digits else f"{value:g}"


def _draw_knocks(ax: Any, results: Mapping[str, Sequence[ShiftResult]], hour: float | None) -> None:
    """The error relative to the pre-knock level around the knock, every seed of every kind
    (of the knock `hour`; None: all)."""
    for color, (kind, runs) in zip(("C0", "C1", "C2"), results.items(), strict=False):
        labelled = False
        for r in runs:
            k = r.knock_window
            if k is None or (hour is not None and r.settings.knock_at_h != hour):
                continue
            w = [x.window - k + 1 for x in r.records if -10 <= x.window - k < 40]
            e = [x.rmse_mm / r.pre_knock_rmse_mm for x in r.records if -10 <= x.window - k < 40]
            ax.plot(w, e, color=color, alpha=0.5, lw=1, label=None if labelled else kind)
            labelled = True


def plot_campaign(results: Mapping[str, Sequence[ShiftResult]], path: Path) -> None:
    """The true error relative to the pre-knock level around the knock, every seed of every
    kind (windows since the knock on the x axis); several knock hours: a panel per hour."""
    first = next(r for runs in results.values() for r in runs)
    hours = _hours(results)
    if len(hours) > 1:
        _plot_hours(results, hours, path)
        return

    def draw(ax: Any) -> None:
        _draw_knocks(ax, results, None)
        ax.axhline(first.settings.recovered_ratio, color="k", lw=1, ls=":", label="1.2x")
        ax.set_xlabel("windows since the knock (1: the first after it)")
        ax.set_ylabel("true RMS error / pre-knock level")
        ax.set_yscale("log")

    plot_shift(path, 0.5, draw, own_axes=True)


def _plot_hours(
    results: Mapping[str, Sequence[ShiftResult]], hours: list[float], path: Path
) -> None:
    """A panel per knock hour, the same axes in each (as plot_campaign's one)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ratio = next(r for runs in results.values() for r in runs).settings.recovered_ratio
    cols = min(len(hours), 2)
    rows = (len(hours) + cols - 1) // cols
    fig, axes = plt.subplots(
        rows, cols, figsize=(6 * cols, 3.6 * rows), sharex=True, sharey=True, squeeze=False
    )
    for ax, hour in zip(axes.flat, hours, strict=False):
        _draw_knocks(ax, results, hour)
        ax.axhline(ratio, color="k", lw=1, ls=":", label=f"{ratio:g}x")
        ax.axvline(0.5, color="k", ls="--", lw=1, label="knock")
        ax.set_yscale("log")
        ax.set_title(f"knock at {hour:g} h")
        ax.grid(alpha=0.3)
    for ax in axes.flat[len(hours) :]:
        ax.set_visible(False)
    for ax in axes[-1]:
        ax.set_xlabel("windows since the knock (1: the first after it)")
    for ax in axes[:, 0]:
        ax.set_ylabel("true RMS error / pre-knock")
    axes.flat[0].legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def load_campaign(path: Path) -> dict[str, list[ShiftResult]]:
    """The runs of a campaign's `shift-knocks.json`, each scored again
    (app.sim.shift_score.scored_from_json)."""
    import json

    doc = json.loads(path.read_text(encoding="utf-8"))
    return {k: [scored_from_json(r) for r in runs] for k, runs in doc["runs"].items()}


def campaign_doc(
    results: Mapping[str, Sequence[ShiftResult]], commands: Sequence[str] = ()
) -> dict[str, Any]:
    """The campaign's json: `rows` (per kind; several knock hours: per kind and hour, each
    with its `knock_at_h`), `overall` (several hours: per kind over them), `per_run` (every
    run's seed, kind, hour, figures and the command that runs it alone, in the order of
    `commands`: the campaign's) and `runs` (every run's shift.json, per kind)."""
    several = len(_hours(results)) > 1
    ordered = [r for runs in results.values() for r in runs]
    rows = [
        kind_row(kind, group)
        for kind, runs in results.items()
        for group in (by_hour(runs).values() if several else [runs])
    ]
    doc: dict[str, Any] = {"rows": rows}
    if several:
        doc["overall"] = [kind_row(kind, runs) for kind, runs in results.items()]
    cmds: list[str | None] = list(commands) or [None] * len(ordered)
    doc["per_run"] = [run_row(r, c) for r, c in zip(ordered, cmds, strict=True)]
    doc["runs"] = {kind: [r.to_json() for r in runs] for kind, runs in results.items()}
    return doc


def write_campaign(
    results: Mapping[str, Sequence[ShiftResult]],
    out: Path,
    command: str,
    *,
    commands: Sequence[str] = (),
) -> list[Path]:
    """`shift-knocks.md`, `.json` and `.png` in `out` (`commands`: the command that runs each
    shift alone, in the order of `results`' runs)."""
    doc = campaign_doc(results, commands)
    md = campaign_markdown(results, command, commands)
    return write_report_files(out, "shift-knocks", md, doc, lambda png: plot_campaign(results, png))
