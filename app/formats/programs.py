"""Files of `rvis compensate`: the targets CSV it reads, the CSV and FANUC `.ls` it writes.

Targets CSV, one of two kinds, told apart by the header:

- poses:  id,x_mm,y_mm,z_mm,w_deg,p_deg,r_deg  intended sensor (TCP) poses in the part frame,
  FANUC W/P/R (R = Rz(r) Ry(p) Rx(w), fixed axes); optional j1_deg..j6_deg on a row: joints
  whose branch that row keeps (all six or none);
- joints: id,j1_deg,...,j6_deg  controller angles taught or planned on the nominal model.

Every bad value is an InputError naming file, line (header = line 1) and field. The `.ls`
program has one joint move per target and the P[] positions in joint representation
(`P[1:"id"]{ GP1: UF : 0, UT : 1, J1=     0.000 deg, ... };`, the layout a controller
exports), which a controller runs as they are:
no inverse kinematics on the controller, so no branch to get wrong. The UF/UT numbers a joint
position records do not move the robot; they are the frames the pendant uses when the position
is shown or converted to Cartesian (docs: README "rvis compensate"), so they default to the
world frame (UF 0) and the first tool frame (UT 1, of the controller's 1..10).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from app.errors import InputError
from app.formats.files import check_joint_limits, csv_number, csv_rows, write_bytes, write_csv
from calib.robot import JointLimits

F64 = NDArray[np.float64]

POSE_COLUMNS = ("id", "x_mm", "y_mm", "z_mm", "w_deg", "p_deg", "r_deg")
JOINT_COLUMNS = ("id", *(f"j{i}_deg" for i in range(1, 7)))
OUT_COLUMNS = (
    *JOINT_COLUMNS,
    "x_mm",
    "y_mm",
    "z_mm",
    "w_deg",
    "p_deg",
    "r_deg",
    *(f"j{i}_original_deg" for i in range(1, 7)),
    "joint_change_deg",
)


@dataclass(frozen=True)
class Targets:
    """Rows of a targets CSV: ids, their line numbers, `kind` 'poses' or 'joints', `values`
    (N, 6) (xyzwpr or joints) and `q_hint_deg` (N, 6) (NaN where a row has none)."""

    path: Path
    kind: str
    ids: list[str]
    lines: list[int]
    values: F64
    q_hint_deg: F64


def read_targets(path: str | Path, limits: JointLimits) -> Targets:
    """Read a poses or joints targets CSV; joints (targets and hints) are checked against the
    limits."""
    path = Path(path)
    try:
        head = path.read_text(encoding="utf-8-sig").splitlines()[:1]
    except (OSError, UnicodeDecodeError):
        head = []  # _rows below reports it, naming the file
    header = {h.strip() for h in head[0].split(",")} if head else set()
    kind = "joints" if "j1_deg" in header and "x_mm" not in header else "poses"
    columns = JOINT_COLUMNS if kind == "joints" else POSE_COLUMNS
    has_hint = kind == "poses" and "j1_deg" in header
    ids: list[str] = []
    lines: list[int] = []
    values: list[list[float]] = []
    hints: list[F64] = []
    seen: set[str] = set()
    for line, row in csv_rows(path, columns):
        tid = row["id"]
        if not tid:
            raise InputError("empty id", file=path, line=line, field="id")
        if tid in seen:
            raise InputError(f"duplicate id '{tid}'", file=path, line=line, field="id")
        v = [csv_number(row, f, path, line) for f in columns[1:]]
        if kind == "joints":
            check_joint_limits(np.array(v), limits, path, line)
        hint = np.full(6, np.nan)
        if has_hint and any(row[f] for f in JOINT_COLUMNS[1:]):
            hint = np.array([csv_number(row, f, path, line) for f in JOINT_COLUMNS[1:]])
            check_joint_limits(hint, limits, path, line)
        ids.append(tid)
        seen.add(tid)
        lines.append(line)
        values.append(v)
        hints.append(hint)
    if not ids:
        raise InputError("no targets in file", file=path)
    return Targets(path, kind, ids, lines, np.array(values), np.array(hints))


def write_result_csv(
    path: str | Path, ids: Sequence[str], q_deg: F64, xyzwpr: F64, q_original_deg: F64
) -> None:
    """Compensated joints, the compensated Cartesian target for a nominal controller (part
    frame), the original joints and the largest joint change, one row per target."""
    change = np.max(np.abs(q_deg - q_original_deg), axis=1)
    rows = [
        [tid, *map(float, q_deg[i]), *map(float, xyzwpr[i]), *map(float, q_original_deg[i]),
         float(change[i])]
        for i, tid in enumerate(ids)
    ]  # fmt: skip
    write_csv(path, OUT_COLUMNS, rows)


@dataclass(frozen=True)
class LsSettings:
    """The `.ls` program: joint-move speed [%], termination, the UF/UT numbers recorded with
    each position (joint positions do not depend on them: module docstring), decimals of the
    joint angles (FANUC writes 3; 0.001 deg is about 0.035 mm at 2 m reach)."""

    speed_percent: int = 10
    termination: str = "FINE"
    uframe: int = 0
    utool: int = 1
    decimals: int = 3

    #: field -> (lowest, highest, what it is): the controller's ranges (R-30iB: user frames
    #: 0 = world and 1..9, tool frames 1..10)
    RANGES: ClassVar[dict[str, tuple[int, int, str]]] = {
        "speed_percent": (1, 100, "a joint speed [%]"),
        "uframe": (0, 9, "a user frame number (0: world)"),
        "utool": (1, 10, "a tool frame number"),
        "decimals": (1, 6, "a number of decimals"),
    }

    def __post_init__(self) -> None:
        for name, (lo, hi, what) in self.RANGES.items():
            value = getattr(self, name)
            if not (isinstance(value, int) and lo <= value <= hi):
                raise ValueError(f"{name} = {value!r}: expected {what} {lo}..{hi}")
        if not re.fullmatch(r"FINE|CNT(100|[1-9]?[0-9])", self.termination):
            raise ValueError(f"termination = {self.termination!r}: expected FINE or CNT0..CNT100")


#: The longest FANUC TP program name (R-30iA and later).
MAX_PROGRAM_NAME = 36


def program_name(path: str | Path) -> str:
    """The program name from the file name: upper case, characters other than letters, digits
    and _ replaced by _, starting with a letter, at most 36 characters (a longer one is an
    error, never cut: the controller would know the program by another name)."""
    name = re.sub(r"[^A-Z0-9_]", "_", Path(path).stem.upper())
    if not name or not name[0].isalpha():
        raise InputError(
            "the program name (from the file name) must start with a letter", file=path
        )
    if len(name) > MAX_PROGRAM_NAME:
        raise InputError(
            f"the program name (from the file name) {name!r} has {len(name)} characters; a"
            f" FANUC program name has at most {MAX_PROGRAM_NAME}: choose a shorter file name",
            file=path,
        )
    return name


def ls_program(
    name: str, ids: Sequence[str], q_deg: F64, settings: LsSettings, when: datetime
) -> str:
    """A FANUC TP program (.ls text) moving in joint motion through the positions q_deg (N, 6)
    [deg] in joint representation, each commented with its target id."""
    stamp = f"DATE {when:%y-%m-%d}  TIME {when:%H:%M:%S}"
    head = [
        f"/PROG  {name}", "/ATTR", "OWNER\t\t= MNEDITOR;", 'COMMENT\t\t= "rvis compensated";',
        "PROG_SIZE\t= 0;", f"CREATE\t\t= {stamp};", f"MODIFIED\t= {stamp};", "FILE_NAME\t= ;",
        "VERSION\t\t= 0;", f"LINE_COUNT\t= {len(ids)};", "MEMORY_SIZE\t= 0;",
        "PROTECT\t\t= READ_WRITE;", "TCD:  STACK_SIZE\t= 0,", "      TASK_PRIORITY\t= 50,",
        "      TIME_SLICE\t= 0,", "      BUSY_LAMP_OFF\t= 0,", "      ABORT_REQUEST\t= 0,",
        "      PAUSE_REQUEST\t= 0;", "DEFAULT_GROUP\t= 1,*,*,*,*;",
        "CONTROL_CODE\t= 00000000 00000000;", "/MN",
    ]  # fmt: skip
    comments = [_comment(tid) for tid in ids]
    moves = [
        f"{k + 1:4d}:J P[{k + 1}:{c}] {settings.speed_percent}% {settings.termination}    ;"
        for k, c in enumerate(comments)
    ]
    positions = [
        "/POS",
        *(
            _position(f'P[{k + 1}:"{c}"]', q, settings)
            for k, (c, q) in enumerate(zip(comments, q_deg, strict=True))
        ),
    ]
    return "\n".join([*head, *moves, *positions, "/END"]) + "\n"


def _comment(tid: str) -> str:
    # a position comment: at most 16 characters; quoted in /POS, bare in /MN (as the
    # controller writes them), so no quotes, brackets or semicolons inside
    return re.sub(r'["\[\];]', "_", tid)[:16]


def _position(label: str, q: F64, s: LsSettings) -> str:
    j = [f"J{i + 1}={q[i]:{s.decimals + 7}.{s.decimals}f} deg" for i in range(6)]
    return (
        f"{label}{{\n   GP1:\n\tUF : {s.uframe}, UT : {s.utool},\t\n"
        f"\t{j[0]},\t{j[1]},\t{j[2]},\n\t{j[3]},\t{j[4]},\t{j[5]}\n}};"
    )


def write_ls(path: str | Path, ids: Sequence[str], q_deg: F64, settings: LsSettings) -> str:
    """Write the program (atomically, as every file rvis writes); its program name."""
    name = program_name(path)
    text = ls_program(name, ids, q_deg, settings, datetime.now())
    write_bytes(path, text.encode("ascii", errors="replace"))
    return name
