"""`rvis export urdf`: the identified system as a URDF (calib/urdf.py).

ROS-Industrial names (base_link, link_1..link_6, tool0, joint_1..joint_6), the part frame as
the root link `part` and the sensor as the fixed link `sensor`; joint angles in URDF convention
(u3 = J3 + J2, every other u = J, in radians).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from app.api import Calibration
from app.commands import add_command
from app.errors import InputError


def register(sub: argparse._SubParsersAction) -> None:
    p = add_command(sub, "export")
    p.add_argument("what", choices=("urdf",), help="what to export")
    p.add_argument("--params", required=True, help="parameters JSON (from rvis identify)")
    p.add_argument("--out", required=True, help="file to write (robot.urdf)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    cal = Calibration.load(args.params)
    out = Path(args.out)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(cal.urdf(), encoding="utf-8")
    except OSError as exc:
        raise InputError(f"cannot write: {exc.strerror or exc}", file=out) from exc
    print(f"wrote {out}: URDF of {args.params} (root link 'part', tip 'sensor')")
    return 0
