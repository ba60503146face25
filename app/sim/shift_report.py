"""What a compressed shift (app.sim.shift) reports: its must-show figures as lines (the demo's
and `rvis experiment shift`'s output), its table per hour (shift.md), its timeline (shift.json),
its plot (shift.png), and the comparison of the estimators on one cell (estimators.md)."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from app.formats.files import dumps_json
from app.sim.shift_result import ShiftResult


def hourly_rows(result: ShiftResult) -> list[dict[str, float]]:
    """Per sim hour: mean temperature, mean true RMSE without and with recalibration, and the
    calibrations applied during that hour."""
    rows = []
    applied = set(result.applied_windows)
    hours = math.ceil(result.settings.hours)
    for h in range(hours):
        recs = [r for r in result.records if h <= r.t_h < h + 1]
        if not recs:
            continue
        rows.append(
            {
                "hour": float(h),
                "temp_c": float(np.mean([r.temp_c for r in recs])),
                "without_mm": float(np.mean([r.rmse_commissioning_mm for r in recs])),
                "with_mm": float(np.mean([r.rmse_mm for r in recs])),
                "max_with_mm": float(np.max([r.rmse_mm for r in recs])),
                "applied": float(sum(r.window in applied for r in recs)),
            }
        )
    return rows


def time_text(scale: float | None) -> str:
    """How the shift's time ran, for its report."""
    return "virtual time" if scale is None else f"virtual time paced at x{scale:g}"


def _windows_text(n: int | None, limit: int) -> str:
    return "never" if n is None else f"{n} window{'s' * (n != 1)} (target <= {limit})"


def summary_lines(result: ShiftResult) -> list[str]:
    """The shift's must-show figures, one per line."""
    s, sm = result.settings, result.summary
    tail = [
        stated_accuracy_text(result),
        _alarms_text(result),
        f"overruns: {sm.overruns} (target 0); windows {sm.windows}, measurements {sm.measurements}"
        f" ({sm.rejected} rejected), calibrations applied {sm.calibrations_applied}, rejected"
        f" {sm.calibrations_rejected}",
        f"true RMSE at the end: {sm.true_rmse_final_mm:.4f} mm with the service,"
        f" {result.records[-1].rmse_commissioning_mm:.4f} mm without recalibration"
        if result.records
        else "no window ran",
    ]
    if not s.knocked:
        return [
            f"no knock; a step attributed to: {result.attribution or 'nothing'} (target nothing)",
            f"suspect intervals: {_spans(result) or 'none'}",
            *tail,
        ]
    mm, deg = s.knock_size()
    axis = "J2" if s.knock == "joint" else s.knock
    what = {"sensor": "the sensor mount", "fixture": "the spheres' frame"}.get(
        s.knock, "one sphere alone" if s.knock == "sphere" else f"the {axis} zero"
    )
    size = {"sensor": f"{mm:g} mm / {deg:g} deg", "fixture": f"{mm:g} mm / {deg:g} deg"}.get(
        s.knock, f"{mm:g} mm" if s.knock == "sphere" else f"{deg:g} deg"
    )
    return [
        f"knock of {what} ({size}) at {s.knock_at_h:g} h (window {result.knock_window}):"
        f" flagged by the step alarm after {_windows_text(result.flagged_after, 3)},"
        f" attributed to: {result.attribution or 'nothing'}",
        f"true RMS within the limit ({result.accuracy_limit_mm:g} mm) after"
        f" {_windows_text(result.within_limit_after, 6)}; back within"
        f" {s.recovered_ratio:g}x of the pre-knock error ({result.pre_knock_rmse_mm:.4f} mm)"
        f" after {_windows_text(result.recovered_after, 3)}",
        _suspects_text(result),
        *tail,
    ]


def stated_accuracy_text(result: ShiftResult) -> str:
    """What the service stated about its accuracy against the truth: the windows whose true
    RMS is within the stated U95, the median U95, the suspect windows and those above the
    limit."""
    recs = result.records
    stated = [r.u95_mm for r in recs if r.u95_mm is not None]
    if not recs or not stated:
        return "stated accuracy: no U95 stated"
    covered = sum(r.u95_mm is not None and r.rmse_mm <= r.u95_mm for r in recs)
    limit = result.accuracy_limit_mm
    above = [r for r in recs if r.rmse_mm > limit]
    return (
        f"stated accuracy: U95 median {float(np.median(stated)):.4f} mm (limit {limit:g} mm);"
        f" true RMS within the stated U95 in {covered} of {len(recs)} windows (target >= 95 %);"
        f" {sum(r.suspect for r in recs)} windows suspect, {sum(r.suspect for r in above)} of"
        f" the {len(above)} above the limit (target >= 98 %)"
    )


def _suspects_text(result: ShiftResult) -> str:
    sc = result.suspect_score
    if sc is None:
        return "suspect intervals: no knock window"
    return (
        f"suspect intervals: {_spans(result) or 'none'}; they cover {len(sc.covered)} windows"
        f" after the knock, {len(sc.bad)} were above {result.settings.recovered_ratio:g}x (recall"
        f" {100 * sc.recall:.0f} %, target 100 %), {sc.extra} covered that were not"
        f" ({100 * sc.extra_share:.0f} % of the covered, target <= 10 %); over the knock's"
        f" episode ({_episode_span(result.knock_window, sc.episode_end)}):"
        f" {len(sc.episode_covered)} of {len(sc.episode_bad)} above covered (recall"
        f" {100 * sc.episode_recall:.0f} %, target >= 95 %)"
    )


def _spans(result: ShiftResult) -> str:
    return ", ".join(
        f"{x['t_start_s'] / 3600:.3f}-"
        + ("open" if x["t_end_s"] is None else f"{x['t_end_s'] / 3600:.3f}")
        + f" h ({x['size_mm'] or 0:.3f} mm)"
        for x in result.suspects
    )


def _episode_span(knock_window: int | None, end: int | None) -> str:
    return "no window above" if end is None else f"windows {knock_window}-{end}"


def _alarms_text(result: ShiftResult) -> str:
    """Step alarm episodes (windows with a new one) before and after the knock."""
    k = result.knock_window or 10**9
    steps = set(result.step_alarm_windows)
    before = len({w for w in steps if w < k})
    after = len(steps) - before
    return f"step alarms (windows with one) before the knock: {before}; after it: {after}"


def markdown(result: ShiftResult, command: str) -> str:
    lines = [
        "# Compressed shift on the simulated line",
        "",
        f"Generated by `{command}` (seed {result.seed}, {time_text(result.scale)},"
        f" {'geometric' if result.settings.geometric else 'rendered'} measurements,"
        f" {result.real_s:.0f} s real time). True RMS error at the line's validation positions"
        " after every window: with the service (parameters in force) and without recalibration"
        " (the commissioning parameters).",
        "",
        *[f"- {line}" for line in summary_lines(result)],
        "",
        "| hour | temperature [C] | RMSE without recalibration [mm] | RMSE with the service [mm]"
        " | max with the service [mm] | calibrations applied |",
        "|---:|---:|---:|---:|---:|---:|",
    ]
    for r in hourly_rows(result):
        lines.append(
            f"| {r['hour']:.0f}-{r['hour'] + 1:.0f} | {r['temp_c']:.2f} | {r['without_mm']:.4f} |"
            f" {r['with_mm']:.4f} | {r['max_with_mm']:.4f} | {r['applied']:.0f} |"
        )
    lines += ["", "![true error over the shift](shift.png)", ""]
    return "\n".join(lines)


def plot_shift(
    path: Path, knock_at_h: float, draw: Callable[[Any], None], *, own_axes: bool = False
) -> None:
    """The shift's figure: `draw(ax)` puts the curves, this the knock, axes and legend
    (`own_axes`: draw labelled the axes itself)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 4.5))
    draw(ax)
    ax.axvline(knock_at_h, color="k", ls="--", lw=1, label="knock")
    if not own_axes:
        ax.set_xlabel("shift time [h]")
        ax.set_ylabel("true RMS error at the validation positions [mm]")
        ax.set_ylim(bottom=0)
    ax.legend(loc="upper left")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot(result: ShiftResult, path: Path) -> None:
    def draw(ax: Any) -> None:
        t_h = [r.t_h for r in result.records]
        ax.plot(
            t_h, [r.rmse_commissioning_mm for r in result.records], label="without recalibration"
        )
        ax.plot(t_h, [r.rmse_mm for r in result.records], label="with the service")
        by_window = {r.window: r.t_h for r in result.records}
        applied = [by_window[w] for w in result.applied_windows if w in by_window]
        if applied:
            ax.plot(applied, [0.0] * len(applied), "g^", ms=5, label="calibration applied")

    plot_shift(path, result.settings.knock_at_h, draw)


def write_report_files(
    out: Path, stem: str, md: str, doc: Any, draw: Callable[[Path], None]
) -> list[Path]:
    """`<stem>.md`, `<stem>.json` and `<stem>.png` in `out` (the figure by `draw(path)`)."""
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / f"{stem}{ext}" for ext in (".md", ".json", ".png")]
    paths[0].write_text(md)
    paths[1].write_text(dumps_json(doc))
    draw(paths[2])
    return paths


def write_outputs(result: ShiftResult, out: Path, command: str, stem: str = "shift") -> list[Path]:
    """`<stem>.md`, `<stem>.json` and `<stem>.png` in `out`."""
    md = markdown(result, command).replace("(shift.png)", f"({stem}.png)")
    return write_report_files(out, stem, md, result.to_json(), lambda png: plot(result, png))


def estimator_rows(results: dict[str, ShiftResult]) -> list[dict[str, Any]]:
    """One row per way of keeping the cell calibrated: no recalibration (the commissioning
    parameters, from the first run), then each estimator: the time-averaged true RMSE over the
    shift, before and after the knock, the worst window, knock flag and recovery."""
    first = next(iter(results.values()))
    k = first.knock_window or 10**9

    def row(name: str, r: ShiftResult, e: list[float]) -> dict[str, Any]:
        w = [rec.window for rec in r.records]
        return {
            "name": name,
            "mean_mm": float(np.mean(e)),
            "before_mm": float(np.mean([x for x, i in zip(e, w, strict=True) if i < k] or [0])),
            "after_mm": float(np.mean([x for x, i in zip(e, w, strict=True) if i >= k] or [0])),
            "max_mm": float(np.max(e)),
        }

    out = [row("no recalibration", first, [x.rmse_commissioning_mm for x in first.records])]
    for name, r in results.items():
        out.append(
            row(name, r, [x.rmse_mm for x in r.records])
            | {
                "flagged_after": r.flagged_after,
                "recovered_after": r.recovered_after,
                "applied": r.summary.calibrations_applied,
                "rejected": r.summary.calibrations_rejected,
                "overruns": r.summary.overruns,
            }
        )
    return out


def estimators_markdown(results: dict[str, ShiftResult], command: str) -> str:
    """The comparison table of `rvis experiment shift --estimator compare`."""
    first = next(iter(results.values()))
    lines = [
        "# Keeping the cell calibrated over a shift: no recalibration, batch, sequential",
        "",
        f"Generated by `{command}` (seed {first.seed}, {time_text(first.scale)}, the same simulated"
        f" cell, warm-up and knock at {first.settings.knock_at_h:g} h in every run; model:"
        f" {first.settings.model or 'the cell file'}). True RMS"
        " error at the line's validation positions after every window, averaged over the shift"
        " and before/after the knock. Batch: identification on the rolling set (24 + 4 held"
        " out) every 24 measurements or when drift is flagged; sequential: an extended Kalman"
        " update per measurement (app/line/inline_seq.py), a candidate every 8 accepted updates,"
        " the same gates; adaptive: the sequential estimator choosing the most informative"
        " planned configuration instead of the next in turn.",
        "",
        "| | mean RMSE [mm] | before the knock [mm] | after the knock [mm] | worst window [mm]"
        " | knock flagged after | back within 1.2x after | applied / rejected | overruns |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in estimator_rows(results):
        extra = (
            f" {_n(r['flagged_after'])} | {_n(r['recovered_after'])} |"
            f" {r['applied']} / {r['rejected']} | {r['overruns']} |"
            if "applied" in r
            else " - | - | - | - |"
        )
        lines.append(
            f"| {r['name']} | {r['mean_mm']:.4f} | {r['before_mm']:.4f} | {r['after_mm']:.4f} |"
            f" {r['max_mm']:.4f} |" + extra
        )
    lines += ["", "![true error over the shift](shift-estimators.png)", ""]
    return "\n".join(lines)


def _n(windows: int | None) -> str:
    return "never" if windows is None else f"{windows} windows"


def plot_estimators(results: dict[str, ShiftResult], path: Path) -> None:
    first = next(iter(results.values()))

    def draw(ax: Any) -> None:
        t_h = [r.t_h for r in first.records]
        ax.plot(t_h, [r.rmse_commissioning_mm for r in first.records], label="no recalibration")
        for name, res in results.items():
            ax.plot([r.t_h for r in res.records], [r.rmse_mm for r in res.records], label=name)

    plot_shift(path, first.settings.knock_at_h, draw)


def write_estimators(results: dict[str, ShiftResult], out: Path, command: str) -> list[Path]:
    """`shift-estimators.md`, `.json` and `.png` in `out`."""
    md, doc = estimators_markdown(results, command), {"rows": estimator_rows(results)}
    return write_report_files(
        out, "shift-estimators", md, doc, lambda png: plot_estimators(results, png)
    )
