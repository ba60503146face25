"""The bodies' results as a plant reads them: one record per body from the state database (its
newest evaluation), and the same values as CSV rows. Light: SQLite and the standard library.

A value is `suspect` when its body was measured inside a suspect interval (from the interval's
start to its end, or to now while it is open) and its values are not the ones computed again with
that interval's correction: measure the body again, or leave the value out of the SPC.

    records(store, since_t=None, body_id=None, last=None) -> [{"body", "time_utc", ..., "values"}]
    csv_text(records) -> the values as CSV, a row each
    show_text(record) -> one body's record in words (`rvis results show`, `rvis state body`)
"""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from typing import Any

from app.inspect.spc import suspect_of
from app.line.states import utc_text
from app.line.store import Store

VALUE_KEYS = (
    "feature", "characteristic", "nominal_mm", "measured_mm", "lower_mm", "upper_mm", "u95_mm",
    "decision", "suspect",
)  # fmt: skip
CSV_HEADER = (
    "body", "time_utc", "evaluation", "params_version", "feature", "characteristic",
    "nominal_mm", "measured_mm", "lower_mm", "upper_mm", "u95_mm", "decision", "suspect",
    "reason",
)  # fmt: skip


def records(
    store: Store,
    since_t: float | None = None,
    body_id: Any = None,
    now_t: float = float("inf"),
    last: int | None = None,
) -> list[dict[str, Any]]:
    """One record per body measured since `since_t` (or the body `body_id`; only the `last` n
    when given), oldest first, each its newest evaluation."""
    intervals = store.suspects()
    bodies = store.bodies(since_t, None, body_id, last=last)
    return [record_of(store, b, intervals, now_t) for b in bodies]


def record_of(
    store: Store, b: dict[str, Any], intervals: Sequence[dict[str, Any]], now_t: float
) -> dict[str, Any]:
    """The record of a body row of `Store.bodies` (its evaluation's values)."""
    suspect = suspect_of(b, intervals, now_t)
    values = []
    for v in store.body_values(int(b["id"]), int(b["evaluation"])):
        row = {k: v[k] for k in VALUE_KEYS if k in v}
        row["suspect"] = suspect is not None and v["measured_mm"] is not None
        row["reason"] = v["reason"]
        values.append(row)
    return {
        "body": b["body_id"], "time_utc": utc_text(float(b["t"])), "part": b["part"],
        "evaluation": b["evaluation"], "params_version": b["params_version"],
        "statement_u95_mm": b["statement_u95_mm"], "ok": bool(b["ok"]),
        "n_nok": b["n_nok"], "n_undecided": b["n_undecided"],
        "n_not_measured": b["n_not_measured"], "suspect_interval": suspect,
        "reevaluated": b["evaluation"] > 0, "values": values,
    }  # fmt: skip


def csv_text(recs: Sequence[dict[str, Any]]) -> str:
    """The records' values as CSV (CSV_HEADER; empty cells for a value not measured)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_HEADER)
    for r in recs:
        for v in r["values"]:
            head = {k: r[k] for k in ("body", "time_utc", "evaluation", "params_version")}
            row = {**v, **head}
            w.writerow(["" if row.get(k) is None else row.get(k) for k in CSV_HEADER])
    return buf.getvalue()


def capability(recs: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per characteristic over the records' values (those measured and not suspect): n, mean,
    sd, Cp = (upper - lower) / 6 sd and Cpk = min(upper - mean, mean - lower) / 3 sd (None
    with fewer than 2 values or no spread)."""
    by: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for r in recs:
        for v in r["values"]:
            if v["measured_mm"] is not None and not v["suspect"]:
                by.setdefault((v["feature"], v["characteristic"]), []).append(v)
    out = []
    for (feature, name), vs in by.items():
        xs = [float(v["measured_mm"]) for v in vs]
        lo, hi = float(vs[0]["lower_mm"]), float(vs[0]["upper_mm"])
        n = len(xs)
        mean = sum(xs) / n
        sd = (sum((x - mean) ** 2 for x in xs) / (n - 1)) ** 0.5 if n > 1 else 0.0
        ok = n > 1 and sd > 0
        out.append(
            {
                "feature": feature, "characteristic": name, "n": n, "mean_mm": mean,
                "sd_mm": sd if n > 1 else None, "lower_mm": lo, "upper_mm": hi,
                "cp": (hi - lo) / (6 * sd) if ok else None,
                "cpk": min(hi - mean, mean - lo) / (3 * sd) if ok else None,
            }
        )  # fmt: skip
    return out


def show_text(r: dict[str, Any]) -> str:
    """One body's record (app.line.body_results) in words: its values with their U95 and
    decisions (`rvis results show`, `rvis state body`)."""
    head = (
        f"body {r['body']} ({r['part']}), measured {r['time_utc']} with parameters version"
        f" {r['params_version']}: {'OK' if r['ok'] else 'NOK'}; the cell stated U95"
        f" {r['statement_u95_mm']:.3f} mm for a point measured then"
        if r["statement_u95_mm"] is not None
        else f"body {r['body']} ({r['part']}), measured {r['time_utc']}: no statement"
    )
    if r["suspect_interval"] is not None:
        head += f"; SUSPECT: measured inside suspect interval {r['suspect_interval']}"
    if r["reevaluated"]:
        head += f"; computed again after a correction (evaluation {r['evaluation']})"
    lines = [head, f"{'characteristic':<10} {'nominal':>10} {'measured':>10} {'dev':>8}"
             f" {'U95':>7}  decision"]  # fmt: skip
    for v in r["values"]:
        key = f"{v['feature']}.{v['characteristic']}"
        if v["measured_mm"] is None:
            lines.append(f"{key:<10} {v['nominal_mm']:>10.3f} {'-':>10} {'-':>8} {'-':>7}"
                         f"  not measured: {v['reason']}")  # fmt: skip
            continue
        dev = v["measured_mm"] - v["nominal_mm"]
        lines.append(
            f"{key:<10} {v['nominal_mm']:>10.3f} {v['measured_mm']:>10.3f} {dev:>+8.3f}"
            f" {v['u95_mm']:>7.3f}  {v['decision']}"
        )
    return "\n".join(lines)
