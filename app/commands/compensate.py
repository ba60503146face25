"""`rvis compensate`: compensated joint targets for a controller that runs its nominal model.

Reads intended sensor poses (part frame, FANUC W/P/R) or joint targets taught on the nominal
model (app/formats/programs.py), compensates them with the identified parameters
(calib/compensate.py) and writes a CSV or a FANUC `.ls` program in joint representation. A row
that cannot be compensated (out of reach, no solution within the limits, a branch change) is
an input error naming the file, line and target: nothing is written then.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from app.api import Calibration, command_xyzwpr
from app.commands import add_command
from app.config import load_cell
from app.errors import InputError
from app.formats.programs import (
    LsSettings,
    Targets,
    program_name,
    read_targets,
    write_ls,
    write_result_csv,
)
from app.sim import compensation as check
from calib.compensate import Compensation, CompensationSettings


def register(sub: argparse._SubParsersAction) -> None:
    p = add_command(sub, "compensate")
    p.add_argument("--params", required=True, help="parameters JSON (from rvis identify)")
    p.add_argument(
        "--targets",
        required=True,
        help="CSV of poses (id,x_mm,y_mm,z_mm,w_deg,p_deg,r_deg [,j1_deg..j6_deg hint]) "
        "or joints (id,j1_deg..j6_deg)",
    )
    p.add_argument("--out", required=True, help="output file (.csv or .ls)")
    p.add_argument(
        "--format", choices=("csv", "ls"), help="output format (default: from --out, else csv)"
    )
    d = CompensationSettings()
    p.add_argument(
        "--max-joint-change",
        type=float,
        default=d.max_joint_change_deg,
        help=f"largest joint change [deg] before a row is refused ({d.max_joint_change_deg:g})",
    )
    ls, r = LsSettings(), LsSettings.RANGES
    for flag, field, text in LS_FLAGS:
        lo, hi, _ = r[field]
        help_text = f"{text}: {lo}..{hi}, default {getattr(ls, field)} (.ls)"
        p.add_argument(flag, type=int, default=getattr(ls, field), help=help_text)
    p.set_defaults(func=run)


#: The .ls options: flag, LsSettings field, what the help says.
LS_FLAGS = (
    ("--speed", "speed_percent", "joint speed [%%]"),
    ("--uframe", "uframe", "user frame number recorded with the positions (0: world)"),
    ("--utool", "utool", "tool frame number recorded with the positions"),
)


def _settings(args: argparse.Namespace) -> tuple[CompensationSettings, LsSettings]:
    """The settings from the options; a bad value is an error naming the flag and the value."""
    top = CompensationSettings.MAX_JOINT_CHANGE_DEG
    if not 0.0 < args.max_joint_change <= top:
        raise InputError(
            f"--max-joint-change {args.max_joint_change:g}: expected degrees in (0, {top:g}]"
        )
    for flag, field, _ in LS_FLAGS:
        lo, hi, what = LsSettings.RANGES[field]
        value = getattr(args, flag.removeprefix("--"))
        if not lo <= value <= hi:
            raise InputError(f"{flag} {value}: expected {what} {lo}..{hi}")
    return (
        CompensationSettings(max_joint_change_deg=args.max_joint_change),
        LsSettings(speed_percent=args.speed, uframe=args.uframe, utool=args.utool),
    )


def _program_name(out: Path) -> str:
    try:
        return program_name(out)
    except InputError as exc:
        raise InputError(f"--out {out}: {exc.reason}") from None


def run(args: argparse.Namespace) -> int:
    settings, ls = _settings(args)
    out = Path(args.out)
    fmt = args.format or ("ls" if out.suffix.lower() == ".ls" else "csv")
    program = _program_name(out) if fmt == "ls" else ""  # a bad name fails before the work
    cal = Calibration.load(args.params)
    targets = read_targets(args.targets, cal.model.limits)
    result = _compensate(cal, targets, settings)
    _refuse_bad_rows(targets, result)
    try:
        if fmt == "ls":
            write_ls(out, targets.ids, result.q_deg, ls)
        else:
            xyzwpr = command_xyzwpr(result)
            write_result_csv(out, targets.ids, result.q_deg, xyzwpr, result.q_nominal_deg)
    except OSError as exc:
        raise InputError(f"cannot write: {exc.strerror or exc}", file=out) from exc
    change = result.joint_change_deg
    what = f"program {program}, UF {ls.uframe}, UT {ls.utool}" if fmt == "ls" else fmt
    print(
        f"compensated {len(targets.ids)} {targets.kind} targets with {args.params}: joint "
        f"change median {np.median(change):.4f} deg, largest {change.max():.4f} deg; "
        f"wrote {out} ({what})"
    )
    return 0


def _compensate(cal: Calibration, t: Targets, settings: CompensationSettings) -> Compensation:
    if t.kind == "joints":
        return cal.compensate_joints(t.values, settings)
    return cal.compensate_poses(t.values, t.q_hint_deg, settings)


def _refuse_bad_rows(t: Targets, result: Compensation) -> None:
    bad = np.flatnonzero(~result.ok)
    if bad.size == 0:
        return
    first = int(bad[0])
    more = f" (and {bad.size - 1} more rows, lines {_lines(t, bad[1:])})" if bad.size > 1 else ""
    raise InputError(
        f"target '{t.ids[first]}': {result.reason[first]}{more}",
        file=t.path,
        line=t.lines[first],
    )


def _lines(t: Targets, rows: np.ndarray) -> str:
    shown = ", ".join(str(t.lines[int(k)]) for k in rows[:10])
    return shown + (", ..." if rows.size > 10 else "")


def run_compensation_experiment(args: argparse.Namespace) -> int:
    """`rvis experiment compensation`: nominal vs compensated pose error of the true robot of
    the simulated cell (app/sim/compensation.py); writes compensation.md to --out."""
    cfg = load_cell(args.cell)
    out = Path(args.out or f"runs/experiment-{time.strftime('%Y%m%d-%H%M%S')}")
    seeds = list(range(args.first_seed, args.first_seed + (args.seeds or 5)))
    print(f"rvis experiment compensation: {len(seeds)} seeds x {args.validation} poses")
    results = check.run(cfg, seeds, args.validation, log=lambda s: print(s, flush=True))
    command = (
        f"rvis experiment compensation --seeds {len(seeds)} --first-seed {args.first_seed} "
        f"--validation {args.validation}"
    )
    text = check.markdown(results, command)
    out.mkdir(parents=True, exist_ok=True)
    (out / "compensation.md").write_text(text, encoding="utf-8")
    print()
    print(text)
    print(f"written {out}/compensation.md")
    return 0
