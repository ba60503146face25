"""Issue 27's figures: what the commissioning reports against what the cell measures, per seed.

    .venv/bin/python bench/truth_validation.py [--seeds 0 1 2 3 4] [--out runs/truth]

For each seed, `rvis commission --sim --yes` runs twice as its own process (rendered, then
`--geometric`) on a fresh state directory; from the journals:

- quick check: the calibration's own spheres from new views against the tracker (the old
  validation);
- workspace: the paper's validation, a sphere on a tracker nest at 20 workspace positions;
- end to end: the truth, the line's 100 validation positions measured through the commissioned
  sensor calibration and parameters (app/sim/truth.py);
- kinematic: the old "true" figure, true sensor-frame centres fed into the commissioned
  parameters (no real system measures this with a calibrated sensor);
- the acceptance test's PF, PS, SD and the calibration's rejected views.

Prints a Markdown table; `--out` keeps the state directories.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


ACCEPTANCE = ("pf_mm", "ps_mm", "sd_mm")


def commission(state: Path, seed: int, geometric: bool) -> tuple[int, dict[str, Any], float]:
    """Run the commissioning; (exit code, the journal's steps by name, seconds)."""
    argv = [sys.executable, "-m", "app", "commission", "--sim", "--yes", "--seed", str(seed)]
    argv += ["--state-dir", str(state)] + (["--geometric"] if geometric else [])
    t0 = time.monotonic()
    done = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True, check=False)
    seconds = time.monotonic() - t0
    journal = state / "commission" / "journal.json"
    steps = {}
    if journal.exists():
        steps = {s["name"]: s for s in json.loads(journal.read_text())["steps"]}
    if done.returncode not in (0, 3):
        print(done.stdout[-2000:], done.stderr[-2000:], file=sys.stderr)
    return done.returncode, steps, seconds


def kinematic_rmse_mm(state: Path, seed: int) -> float:
    """The old figure: perfect-sensor centres at the line's validation positions."""
    from app.config import load_cell
    from app.formats.params import from_json
    from app.sim.cell import make_cell
    from app.sim.line_setup import simline_settings
    from app.sim.truth import EndToEndTruth, true_rmse_mm
    from fakes.line import SimLine

    cfg = load_cell(None)
    model, x = from_json(state / "commission" / "params.json")
    cell = make_cell(cfg, seed=seed)
    line = SimLine(cell, simline_settings(cfg, geometric=True))
    truth = EndToEndTruth(cell.sensor, None, ())
    return true_rmse_mm(line, truth, model, x)


def row(seed: int, root: Path) -> dict[str, Any]:
    out: dict[str, Any] = {"seed": seed}
    for kind, geometric in (("rendered", False), ("geometric", True)):
        state = root / f"{kind}-{seed}"
        shutil.rmtree(state, ignore_errors=True)
        code, steps, seconds = commission(state, seed, geometric)
        res = {k: v.get("results", {}) for k, v in steps.items()}
        out[kind] = {
            "exit": code,
            "seconds": seconds,
            "quick_mm": res.get("validation", {}).get("rmse_mm"),
            "workspace_mm": res.get("workspace", {}).get("rmse_mm"),
            "workspace_95_mm": res.get("workspace", {}).get("rmse_95_interval_mm"),
            "true_mm": res.get("workspace", {}).get("true_rmse_mm")
            or res.get("validation", {}).get("true_rmse_mm"),
            "rejected": len(res.get("calibration", {}).get("rejected", [])),
            "acceptance": {k: res.get("acceptance", {}).get(k) for k in ACCEPTANCE},
            "failed": [k for k, v in steps.items() if v["status"] != "passed"],
        }
        if (state / "commission" / "params.json").exists():
            out[kind]["kinematic_mm"] = kinematic_rmse_mm(state, seed)
    return out


def fmt(v: Any, scale: float = 1.0, digits: int = 4) -> str:
    return "-" if v is None else f"{scale * v:.{digits}f}"


def table(rows: list[dict[str, Any]]) -> str:
    head = (
        "| seed | quick check | workspace (95 %) | end to end | workspace / truth | "
        'quick / truth | old "true" (kinematic) | geometric truth | rendered / geometric | '
        "rejected of 24 | PF / PS / SD um | exit |"
    )
    lines = [head, "|" + "---:|" * 12]
    for r in rows:
        a, g = r["rendered"], r["geometric"]
        t, gt = a["true_mm"], g["true_mm"]
        ws = a["workspace_95_mm"]
        acc = a["acceptance"]
        pps = " / ".join(fmt(acc[k], 1000, 1) for k in ACCEPTANCE)
        lines.append(
            f"| {r['seed']} | {fmt(a['quick_mm'])} | {fmt(a['workspace_mm'])}"
            f" ({fmt(ws[0] if ws else None, 1, 3)}-{fmt(ws[1] if ws else None, 1, 3)}) |"
            f" {fmt(t)} | {fmt(a['workspace_mm'] / t if a['workspace_mm'] and t else None, 1, 2)} |"
            f" {fmt(a['quick_mm'] / t if a['quick_mm'] and t else None, 1, 2)} |"
            f" {fmt(a.get('kinematic_mm'))} | {fmt(gt)} |"
            f" {fmt(t / gt if t and gt else None, 1, 2)} | {a['rejected']} | {pps} |"
            f" {a['exit']}{' ' + ','.join(a['failed']) if a['failed'] else ''} |"
        )
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--out", type=Path, help="keep the state directories here")
    args = ap.parse_args()
    root = args.out or Path(tempfile.mkdtemp(prefix="rvis-truth-"))
    root.mkdir(parents=True, exist_ok=True)
    rows = []
    for seed in args.seeds:
        rows.append(row(seed, root))
        print(json.dumps(rows[-1]), flush=True)
    print(table(rows))
    (root / "truth_validation.json").write_text(json.dumps(rows, indent=2))
    if args.out is None:
        shutil.rmtree(root, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
