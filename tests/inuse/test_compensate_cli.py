"""`rvis compensate` end to end on the simulated cell: the joints it writes (CSV or .ls) bring
the true robot to the intended poses; every bad input is one line naming file, line and field
(or target), exit code 2."""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import numpy as np
import pytest

from app.commands.cli import main
from calib.wpr import pose_from_xyzwpr, xyzwpr_from_pose
from tests.inuse.conftest import Calibrated, standoff_error_mm


def run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(argv)
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def write_joints(path: Path, q_deg: np.ndarray) -> Path:
    rows = [f"T{i:02d}," + ",".join(f"{v:.9f}" for v in q) for i, q in enumerate(q_deg)]
    path.write_text("id," + ",".join(f"j{i}_deg" for i in range(1, 7)) + "\n" + "\n".join(rows))
    return path


def write_poses(path: Path, xyzwpr: np.ndarray, extra: str = "") -> Path:
    rows = [f"P{i:02d}," + ",".join(f"{v:.9f}" for v in p) for i, p in enumerate(xyzwpr)]
    path.write_text("id,x_mm,y_mm,z_mm,w_deg,p_deg,r_deg\n" + "\n".join(rows) + extra)
    return path


def read_result(path: Path) -> tuple[np.ndarray, np.ndarray]:
    with path.open() as fh:
        rows = list(csv.DictReader(fh))
    q = np.array([[float(r[f"j{i}_deg"]) for i in range(1, 7)] for r in rows])
    cart = np.array([[float(r[k]) for k in ("x_mm", "y_mm", "z_mm", "w_deg", "p_deg", "r_deg")]
                     for r in rows])  # fmt: skip
    return q, cart


def test_joint_targets_compensated_to_csv(
    calibrated: Calibrated, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    c = calibrated
    targets = write_joints(tmp_path / "taught.csv", c.views_deg)
    out = tmp_path / "comp.csv"
    code, stdout, _ = run(
        ["compensate", "--params", str(c.params), "--targets", str(targets), "--out", str(out)],
        capsys,
    )
    assert code == 0, stdout
    assert "compensated 40 joints targets" in stdout
    q, cart = read_result(out)
    T_intended = c.model.fk(c.model.nominal_x(), c.views_deg)
    before = standoff_error_mm(c.cell, c.views_deg, T_intended)
    after = standoff_error_mm(c.cell, q, T_intended)
    assert np.sqrt(np.mean(before**2)) > 1.0
    assert np.sqrt(np.mean(after**2)) < 0.1
    # the Cartesian columns: where the nominal controller believes these joints put the sensor
    T_cmd = c.model.fk(c.model.nominal_x(), q)
    # (6 decimals in the file: 1e-6 deg at 2 m is 3.5e-5 mm)
    assert np.abs(pose_from_xyzwpr(cart)[:, :3, 3] - T_cmd[:, :3, 3]).max() < 1e-4
    assert np.abs(pose_from_xyzwpr(cart)[:, :3, :3] - T_cmd[:, :3, :3]).max() < 1e-7


def test_pose_targets_give_the_joints_of_the_same_poses_taught_as_joints(
    calibrated: Calibrated, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    c = calibrated
    q_views = c.views_deg[:10]
    wpr = xyzwpr_from_pose(c.model.fk(c.model.nominal_x(), q_views))
    by_joints = tmp_path / "j.csv"
    by_poses = tmp_path / "p.csv"
    params = ["--params", str(c.params)]
    args = ["compensate", *params, "--targets"]
    assert run([*args, str(write_joints(tmp_path / "tj.csv", q_views)), "--out", str(by_joints)],
               capsys)[0] == 0  # fmt: skip
    # the hint columns keep each row on the branch the joints were taught on
    hinted = tmp_path / "tp.csv"
    lines = write_poses(hinted, wpr).read_text().splitlines()
    lines[0] += "," + ",".join(f"j{i}_deg" for i in range(1, 7))
    for k in range(1, len(lines)):
        lines[k] += "," + ",".join(f"{v:.9f}" for v in q_views[k - 1])
    hinted.write_text("\n".join(lines) + "\n")
    assert run([*args, str(hinted), "--out", str(by_poses)], capsys)[0] == 0
    q_j, _ = read_result(by_joints)
    q_p, _ = read_result(by_poses)
    assert np.abs(q_j - q_p).max() < 1e-5  # the CSV's 6 decimals


def test_ls_program_holds_the_compensated_joints(
    calibrated: Calibrated, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    c = calibrated
    targets = write_joints(tmp_path / "taught.csv", c.views_deg[:5])
    csv_out, ls_out = tmp_path / "comp.csv", tmp_path / "insp_01.ls"
    base = ["compensate", "--params", str(c.params), "--targets", str(targets)]
    assert run([*base, "--out", str(csv_out)], capsys)[0] == 0
    code, stdout, _ = run([*base, "--out", str(ls_out), "--speed", "25"], capsys)
    assert code == 0 and "(program INSP_01, UF 0, UT 1)" in stdout
    text = ls_out.read_text()
    assert text.startswith("/PROG  INSP_01\n/ATTR\n") and text.endswith("/END\n")
    assert "LINE_COUNT\t= 5;" in text
    moves = re.findall(r"^\s+(\d+):J P\[(\d+):(T\d+)\] 25% FINE    ;$", text, re.M)
    assert [m[:2] for m in moves] == [(str(k), str(k)) for k in range(1, 6)]
    positions = re.findall(
        r'P\[(\d+):"(T\d+)"\]\{\n   GP1:\n\tUF : 0, UT : 1,\t\n\t'
        + r",\s*".join(rf"J{i}=\s*(-?\d+\.\d{{3}}) deg" for i in range(1, 7))
        + r"\n\};",
        text,
    )
    assert [p[1] for p in positions] == [f"T{k:02d}" for k in range(5)]
    q_ls = np.array([[float(v) for v in p[2:]] for p in positions])
    q_csv, _ = read_result(csv_out)
    assert np.abs(q_ls - q_csv).max() <= 0.0005 + 1e-9


def test_bad_inputs_are_one_line_errors_naming_the_row(
    calibrated: Calibrated, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    c = calibrated
    wpr = xyzwpr_from_pose(c.model.fk(c.model.nominal_x(), c.views_deg[:3]))
    base = ["compensate", "--params", str(c.params), "--out", str(tmp_path / "o.csv")]
    far = wpr.copy()
    far[1, 0] += 5000.0
    code, _, err = run([*base, "--targets", str(write_poses(tmp_path / "far.csv", far))], capsys)
    assert code == 2
    assert re.search(r"far\.csv:3: target 'P01': out of reach", err), err
    assert err.count("\n") == 1
    bad = write_poses(tmp_path / "bad.csv", wpr, extra="\nP09,1,2,abc,0,0,0\n")
    code, _, err = run([*base, "--targets", str(bad)], capsys)
    assert code == 2 and "bad.csv:5: field 'z_mm': 'abc' is not a number" in err
    dup = write_poses(tmp_path / "dup.csv", wpr, extra="\nP01,1,2,3,0,0,0\n")
    code, _, err = run([*base, "--targets", str(dup)], capsys)
    assert code == 2 and "dup.csv:5: field 'id': duplicate id 'P01'" in err
    q = c.views_deg[:2].copy()
    q[1, 1] = 150.0  # J2 limit 135
    code, _, err = run([*base, "--targets", str(write_joints(tmp_path / "j.csv", q))], capsys)
    assert code == 2 and "j.csv:3: field 'j2_deg': 150 deg is outside the joint limits" in err
    assert not (tmp_path / "o.csv").exists()
    ls_base = [*base[:-1], str(tmp_path / "1st.ls"), "--targets", str(tmp_path / "j.csv")]
    q[1, 1] = 100.0
    write_joints(tmp_path / "j.csv", q)
    code, _, err = run(ls_base, capsys)
    assert code == 2 and "1st.ls: the program name (from the file name) must start" in err


@pytest.mark.parametrize(
    ("option", "message"),
    [
        (["--utool", "0"], "--utool 0: expected a tool frame number 1..10"),
        (["--utool", "11"], "--utool 11: expected a tool frame number 1..10"),
        (["--uframe", "10"], "--uframe 10: expected a user frame number (0: world) 0..9"),
        (["--uframe", "-1"], "--uframe -1: expected a user frame number (0: world) 0..9"),
        (["--speed", "0"], "--speed 0: expected a joint speed [%] 1..100"),
        (["--speed", "150"], "--speed 150: expected a joint speed [%] 1..100"),
        (["--max-joint-change", "0"], "--max-joint-change 0: expected degrees in (0, 180]"),
        (["--max-joint-change", "nan"], "--max-joint-change nan: expected degrees in (0, 180]"),
        (
            ["--out", "a_long_inspection_program_name_of_cell_4.ls"],
            "--out a_long_inspection_program_name_of_cell_4.ls: the program name (from the file"
            " name) 'A_LONG_INSPECTION_PROGRAM_NAME_OF_CELL_4' has 40 characters; a FANUC"
            " program name has at most 36",
        ),
    ],
)
def test_a_bad_option_names_the_flag_and_the_value(
    calibrated: Calibrated,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    option: list[str],
    message: str,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The range errors named neither flag nor value (and mentioned `decimals`, no option, or
    `speed_percent`); a long output name was cut to 36 characters without a word."""
    monkeypatch.chdir(tmp_path)  # a relative --out lands here
    targets = write_joints(tmp_path / "t.csv", calibrated.views_deg[:2])
    out = tmp_path / "prog.ls"
    argv = ["compensate", "--params", str(calibrated.params), "--targets", str(targets)]
    code, _, err = run([*argv, "--out", str(out), *option], capsys)
    assert code == 2 and err.count("\n") == 1, err
    assert f"rvis compensate: error: {message}" in err
    assert "decimals" not in err and "speed_percent" not in err
    assert not out.exists() and not list(tmp_path.glob("*.ls"))


def test_the_tool_and_frame_numbers_reach_the_program(
    calibrated: Calibrated, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    targets = write_joints(tmp_path / "t.csv", calibrated.views_deg[:2])
    name = "P" * 36  # the longest name is kept whole
    out = tmp_path / f"{name}.ls"
    argv = ["compensate", "--params", str(calibrated.params), "--targets", str(targets)]
    assert run([*argv, "--out", str(out), "--utool", "10", "--uframe", "3"], capsys)[0] == 0
    text = out.read_text()
    assert text.startswith(f"/PROG  {name}\n")
    assert text.count("UF : 3, UT : 10,") == 2


def test_parameters_of_another_model_are_refused(
    calibrated: Calibrated, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    doc = json.loads(calibrated.params.read_text())
    doc["model"]["name"] = "abb-irb6700-dh"
    other = tmp_path / "other.json"
    other.write_text(json.dumps(doc))
    targets = write_joints(tmp_path / "t.csv", calibrated.views_deg[:2])
    for argv in (
        ["compensate", "--params", str(other), "--targets", str(targets), "--out", "x.csv"],
        ["export", "urdf", "--params", str(other), "--out", str(tmp_path / "r.urdf")],
    ):
        code, _, err = run(argv, capsys)
        assert code == 2
        assert "other.json: field 'model.name': parameters of model 'abb-irb6700-dh'" in err
