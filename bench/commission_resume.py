"""A rendered commissioning killed (SIGKILL) during its calibration step, then resumed (issue
30, item 1, "must show": three points of the step).

One uninterrupted `rvis commission --sim` (rendered) is the reference; then, for each kill
point, a fresh commissioning is killed when its output reaches `calibration view K/N` and run
again (no --restart) until it ends. Each resumed run must end 0 with the calibration step's
results (measurements, views rejected, residual RMS) and its measurements file identical to the
reference's, and the later steps' figures too.

    nice -n 5 .venv/bin/python bench/commission_resume.py [--views 2 12 23] [--out DIR]

The figures go to `--out` (default a temporary folder) as `commission_resume.json` and are
printed as a table (docs/results/commission-resume.md keeps the last run's).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
#: the cell of tests/app/test_commission.py's rendered run (15 deg planning grid, 16 frames a
#: sweep, one validation view a sphere)
CELL = (
    "[planning]\ngrid_step_deg = 15.0\n[sweep]\nn_frames = 16\n[commission]\nvalidation_views = 1\n"
)
COMPARED = ("calibration", "acceptance", "validation", "workspace")


def _argv(cell: Path, state: Path) -> list[str]:
    return [sys.executable, "-m", "app", "commission", "--sim", "--yes", "--cell", str(cell),
            "--state-dir", str(state)]  # fmt: skip


def _env() -> dict[str, str]:
    return os.environ | {"PYTHONUNBUFFERED": "1", "PYTHONPATH": str(ROOT)}


def run_to_end(cell: Path, state: Path) -> tuple[int, float]:
    t0 = time.monotonic()
    done = subprocess.run(_argv(cell, state), cwd=ROOT, env=_env(), capture_output=True, text=True)
    if done.returncode:
        print(done.stdout[-3000:], done.stderr[-3000:], file=sys.stderr)
    return done.returncode, time.monotonic() - t0


def run_and_kill(cell: Path, state: Path, marker: str) -> float:
    """Run until `marker` is printed, then SIGKILL; seconds from the start to the kill."""
    t0 = time.monotonic()
    with subprocess.Popen(
        _argv(cell, state), cwd=ROOT, env=_env(), stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT, text=True,
    ) as child:  # fmt: skip
        assert child.stdout is not None
        for line in child.stdout:
            if marker in line:
                child.send_signal(signal.SIGKILL)
                break
        child.wait(60)
    if child.returncode != -signal.SIGKILL:
        raise SystemExit(f"{marker!r} never printed (exit {child.returncode})")
    return time.monotonic() - t0


def figures(state: Path) -> dict[str, Any]:
    report = json.loads((state / "commission" / "commission.json").read_text(encoding="utf-8"))
    steps = {s["name"]: s for s in report["steps"]}
    cal = steps["calibration"]
    out: dict[str, Any] = {
        "runs_of_calibration": 1 + len(cal.get("earlier", [])),
        "measurements_csv": (state / "commission" / "calibration_measurements.csv").read_text(
            encoding="utf-8"
        ),
    }
    for name in COMPARED:
        out[name] = {k: v for k, v in steps[name]["results"].items() if k != "seconds"}
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, nargs="+", default=[2, 12, 23], help="kill at view K")
    ap.add_argument("--out", type=Path, help="folder for the state directories and figures")
    args = ap.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="rvis-commission-resume-"))
    out.mkdir(parents=True, exist_ok=True)
    cell = out / "cell.toml"
    cell.write_text(CELL, encoding="utf-8")
    code, seconds = run_to_end(cell, out / "reference")
    ref = figures(out / "reference")
    rows: list[dict[str, Any]] = [
        {"kill": "none", "exit": code, "seconds": round(seconds, 1), "same": True, **_short(ref)}
    ]
    n = ref["calibration"]["measurements"] + len(ref["calibration"]["rejected"])
    for k in args.views:
        state = out / f"kill-{k}"
        killed_s = run_and_kill(cell, state, f"calibration view {k}/{n} ")
        code, seconds = run_to_end(cell, state)
        got = figures(state)
        same = all(got[s] == ref[s] for s in COMPARED) and (
            got["measurements_csv"] == ref["measurements_csv"]
        )
        rows.append(
            {
                "kill": f"view {k}/{n} ({killed_s:.1f} s)",
                "exit": code,
                "seconds": round(seconds, 1),
                "same": same,
                **_short(got),
            }
        )
    doc = {"cell": CELL, "rows": rows}
    (out / "commission_resume.json").write_text(json.dumps(doc, indent=2), encoding="utf-8")
    print("| killed at | resumed run exit | its time [s] | calibration runs | rejected |"
          " residual RMS [mm] | validation RMSE [mm] | same as uninterrupted |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|---:|---|")
    for r in rows:
        print(
            f"| {r['kill']} | {r['exit']} | {r['seconds']} | {r['runs']} | {r['rejected']} |"
            f" {r['rms_mm']:.6f} | {r['validation_rmse_mm']:.6f} | {'yes' if r['same'] else 'NO'} |"
        )
    print(f"figures: {out / 'commission_resume.json'}")
    return 0 if all(r["exit"] == 0 and r["same"] for r in rows) else 1


def _short(f: dict[str, Any]) -> dict[str, Any]:
    return {
        "runs": f["runs_of_calibration"],
        "rejected": len(f["calibration"]["rejected"]),
        "rms_mm": f["calibration"]["rms_mm"],
        "validation_rmse_mm": f["validation"]["rmse_mm"],
    }


if __name__ == "__main__":
    raise SystemExit(main())
