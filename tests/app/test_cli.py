"""The command line: the offline workflow end to end, and every bad input as a one-line error
with exit code 2 naming file, line and field."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.app.conftest import Cli


def test_offline_workflow(simdir: Path, tmp_path: Path, cli: Cli) -> None:
    params = tmp_path / "params.json"
    code, out, _ = cli(
        ["identify", "--targets", str(simdir / "calibration_targets.csv"),
         "--measurements", str(simdir / "calibration_measurements.csv"),
         "--out", str(params)])  # fmt: skip
    assert code == 0 and "rank 30" in out
    doc = json.loads(params.read_text())
    assert doc["rank"] == 30 and len([p for p in doc["parameters"] if p["identified"]]) == 30
    errors = tmp_path / "errors.csv"
    code, out, _ = cli(
        ["validate", "--params", str(params), "--json", "--out", str(errors),
         "--targets", str(simdir / "validation_targets.csv"),
         "--measurements", str(simdir / "validation_measurements.csv")])  # fmt: skip
    stats = json.loads(out)
    assert code == 0 and stats["identified"]["n"] == 40
    assert stats["nominal"]["rmse_mm"] / stats["identified"]["rmse_mm"] > 20
    assert errors.read_text().splitlines()[0] == "target,x_mm,y_mm,z_mm,ex_mm,ey_mm,ez_mm,e_mm"
    code, out, _ = cli(
        ["observability", "--json", "--measurements", str(simdir / "calibration_measurements.csv")]
    )
    obs = json.loads(out)
    assert code == 0 and obs["rank"] == 30 and set(obs["indices"]) == {"O1", "O2", "O3", "O4", "O5"}


def corrupt(src: Path, dst: Path, line: int, column: str, value: str) -> Path:
    rows = src.read_text().splitlines()
    header = rows[0].split(",")
    cells = rows[line - 1].split(",")
    cells[header.index(column)] = value
    rows[line - 1] = ",".join(cells)
    dst.write_text("\n".join(rows) + "\n")
    return dst


def identify_args(simdir: Path, tmp_path: Path, meas: Path | None = None,
                  targets: Path | None = None) -> list[str]:  # fmt: skip
    return [
        "identify",
        "--targets", str(targets or simdir / "calibration_targets.csv"),
        "--measurements", str(meas or simdir / "calibration_measurements.csv"),
        "--out", str(tmp_path / "p.json"),
    ]  # fmt: skip


BAD_MEASUREMENTS = [
    ("j2_deg", 5, "abc", "m.csv:5: field 'j2_deg': 'abc' is not a number"),
    ("sz_mm", 3, "nan", "m.csv:3: field 'sz_mm': 'nan' is not a finite number"),
    ("target", 4, "P9", "m.csv:4: field 'target': unknown target id 'P9'"),
    ("j5_deg", 6, "130", "m.csv:6: field 'j5_deg': 130 deg is outside the joint limits"),
]


@pytest.mark.parametrize(("column", "line", "value", "message"), BAD_MEASUREMENTS)
def test_bad_measurement_values(
    simdir: Path, tmp_path: Path, cli: Cli,
    column: str, line: int, value: str, message: str,
) -> None:  # fmt: skip
    bad = corrupt(simdir / "calibration_measurements.csv", tmp_path / "m.csv", line, column, value)
    code, _, err = cli(identify_args(simdir, tmp_path, meas=bad))
    assert code == 2
    assert message in err and str(tmp_path) in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_missing_column(simdir: Path, tmp_path: Path, cli: Cli) -> None:
    src = (simdir / "calibration_measurements.csv").read_text().replace("sy_mm", "sy")
    (tmp_path / "m.csv").write_text(src)
    code, _, err = cli(identify_args(simdir, tmp_path, meas=tmp_path / "m.csv"))
    assert code == 2 and "m.csv:1: field 'sy_mm': missing column" in err


def test_duplicate_target(simdir: Path, tmp_path: Path, cli: Cli) -> None:
    rows = (simdir / "calibration_targets.csv").read_text().splitlines()
    (tmp_path / "t.csv").write_text("\n".join([*rows, rows[2]]) + "\n")
    code, _, err = cli(identify_args(simdir, tmp_path, targets=tmp_path / "t.csv"))
    assert code == 2 and "t.csv:6: field 'target': duplicate target 'P2'" in err


def test_too_few_measurements(simdir: Path, tmp_path: Path, cli: Cli) -> None:
    rows = (simdir / "calibration_measurements.csv").read_text().splitlines()
    (tmp_path / "m.csv").write_text("\n".join(rows[:8]) + "\n")
    code, _, err = cli(identify_args(simdir, tmp_path, meas=tmp_path / "m.csv"))
    assert code == 2 and "7 measurements give 21 equations for 30 parameters" in err


def test_degenerate_configurations(simdir: Path, tmp_path: Path, cli: Cli) -> None:
    rows = (simdir / "calibration_measurements.csv").read_text().splitlines()
    firsts = [rows[1 + 6 * k] for k in range(4)]

    def nudged(row: str, k: int) -> str:  # the same configuration, another reading
        *head, sz = row.split(",")
        return ",".join([*head, f"{float(sz) + 0.001 * k:.6f}"])

    body = [nudged(r, k) for r in firsts for k in range(6)]
    (tmp_path / "m.csv").write_text("\n".join([rows[0], *body]))
    code, _, err = cli(identify_args(simdir, tmp_path, meas=tmp_path / "m.csv"))
    assert code == 2 and "m.csv: identification Jacobian has rank" in err
    assert "not identifiable together" in err


def test_duplicate_rows_named(simdir: Path, tmp_path: Path, cli: Cli) -> None:
    rows = (simdir / "calibration_measurements.csv").read_text().splitlines()
    (tmp_path / "m.csv").write_text("\n".join([*rows, rows[3]]) + "\n")
    code, _, err = cli(identify_args(simdir, tmp_path, meas=tmp_path / "m.csv"))
    assert code == 2 and f"m.csv:{len(rows) + 1}: duplicate of line 4" in err


def test_redundant_parameter_named(simdir: Path, tmp_path: Path, cli: Cli) -> None:
    code, _, err = cli([*identify_args(simdir, tmp_path), "--add-param", "d3"])
    assert code == 2 and "{d3, d2}" in err.replace("{d2, d3}", "{d3, d2}")


def test_unreadable_file(simdir: Path, tmp_path: Path, cli: Cli) -> None:
    code, _, err = cli(identify_args(simdir, tmp_path, meas=tmp_path / "nope.csv"))
    assert code == 2 and "nope.csv: cannot read file: No such file or directory" in err
    (tmp_path / "bin.csv").write_bytes(b"\xff\xfe\x00garbage")
    code, _, err = cli(identify_args(simdir, tmp_path, meas=tmp_path / "bin.csv"))
    assert code == 2 and "bin.csv" in err and "Traceback" not in err


def test_bad_params_json(simdir: Path, tmp_path: Path, cli: Cli) -> None:
    (tmp_path / "p.json").write_text('{"format": "rvis-parameters",\n "model": ')
    code, _, err = cli(
        ["validate", "--params", str(tmp_path / "p.json"),
         "--targets", str(simdir / "validation_targets.csv"),
         "--measurements", str(simdir / "validation_measurements.csv")])  # fmt: skip
    assert code == 2 and "p.json:2: invalid JSON" in err


def test_bad_cell_file(simdir: Path, tmp_path: Path, cli: Cli) -> None:
    (tmp_path / "cell.toml").write_text("[frames]\n\npart_base_xyz_mm = [1, 2]\n")
    cell = str(tmp_path / "cell.toml")
    code, _, err = cli([*identify_args(simdir, tmp_path), "--cell", cell])
    assert (
        code == 2 and "cell.toml:3: [frames] part_base_xyz_mm: expected a list of 3 numbers" in err
    )


def test_demo_writes_a_report(tmp_path: Path, cli: Cli) -> None:
    code, out, _ = cli(
        ["demo", "--out", str(tmp_path / "run"), "--validation", "30", "--geometric", "--no-line"]
    )
    assert code == 0 and "RMSE improved" in out
    assert not (tmp_path / "run" / "line.png").exists()  # --no-line: no line part
    report = json.loads((tmp_path / "run" / "report.json").read_text())
    assert report["improvement_factor"] > 20 and report["rank"] == 30
    for name in ("report.md", "params.json", "validation_errors.png"):
        assert (tmp_path / "run" / name).stat().st_size > 0
    b = report["remaining_error_breakdown_rmse_mm"]
    assert b["compliance_alone"] > 0 and b["noise_alone"] > 0
    planned = report["planned"]
    assert planned["placement"] == "fixed" and planned["n_measurements"] == 24
    assert planned["observability"]["O1"] > report["observability"]["O1"]
    assert planned["rank"] == 30
    for name in ("plan.json", "params_planned.json", "planned_measurements.csv"):
        assert (tmp_path / "run" / name).stat().st_size > 0
    m = report["measurement"]
    assert m["path"] == "geometric" and "rendered" not in m
    # the robot's repeatability (about 22 um per axis) and the sensor's 5 um: about 40 um in 3D
    assert 20 < m["validation"]["centre_error_rms_um"] < 50
    assert "Measurements: geometric" in out


@pytest.mark.slow  # started first on a worker (tests/conftest.py)
def test_demo_renders_by_default(tmp_path: Path, cli: Cli) -> None:
    """Rendered sweeps measured by the vision pipeline (4 x 4 calibration + 3 validation sweeps
    in this process): the centres agree with the cell's truth to a few um, the report says so
    (the robot repeats exactly here: its stops' 23 um per axis would be in the centre error)."""
    cell = tmp_path / "cell.toml"
    cell.write_text("[calibration]\nconfigs_per_sphere = 4\n[simulation]\nrepeatability_mm = 0.0\n")
    code, out, _ = cli(
        [
            "demo",
            "--out",
            str(tmp_path / "run"),
            "--validation",
            "3",
            "--workers",
            "1",
            "--cell",
            str(cell),
            "--placement",
            "none",
            "--sensor-model",
            "truth",
            "--no-line",
        ]
    )
    assert code == 0 and "rendered sweeps on 1 worker" in out
    assert "rendered and measured 10 sweeps" in out  # progress
    report = json.loads((tmp_path / "run" / "report.json").read_text())
    m = report["measurement"]
    assert m["path"] == "rendered"
    assert m["calibration"]["n"] == 16 and m["validation"]["n"] == 3
    assert m["calibration"]["centre_error_rms_um"] < 10
    r = m["rendered"]
    rejected = m["calibration"]["rejected"] + m["validation"]["rejected"]
    assert r["sweeps"] == 19 + rejected and r["rejected"] == rejected
    assert r["frames_per_sweep"] == 24 and r["render_ms_per_sweep"] > 0
    assert report["rank"] == 30 and report["improvement_factor"] > 20
    assert "Measurements: rendered sweeps" in out and "Rendering: " in out
    md = (tmp_path / "run" / "report.md").read_text()
    assert "rejected views" in md


def test_demo_bad_workers(tmp_path: Path, cli: Cli) -> None:
    code, _, err = cli(["demo", "--out", str(tmp_path / "run"), "--workers", "0"])
    assert code == 2 and "--workers" in err


def test_identify_with_the_compliant_model_from_the_cell_file(
    simdir: Path, tmp_path: Path, cli: Cli
) -> None:
    """[calibration] model = "compliant": the 30 plus the three lumped compliance terms are
    identified, the parameters file says which model, and its residual is below the rigid one
    (the simulated robot's arm does bend under gravity)."""
    cell = tmp_path / "cell.toml"
    cell.write_text('[calibration]\nmodel = "compliant"\n')
    code, text, _ = cli([*identify_args(simdir, tmp_path), "--cell", str(cell), "--json"])
    compliant = json.loads(text)
    doc = json.loads((tmp_path / "p.json").read_text())
    code_rigid, text_rigid, _ = cli([*identify_args(simdir, tmp_path), "--json"])
    rigid = json.loads(text_rigid)
    assert code == code_rigid == 0 and compliant["rank"] == 33 and rigid["rank"] == 30
    assert doc["model"]["kind"] == "compliant"
    assert compliant["residuals"]["rms_mm"] < rigid["residuals"]["rms_mm"]
