"""Results that never lie and clean errors on every path: each defect class of a user's bad
input, with the exit code and the one-line message rvis gives, and the files it leaves."""

from __future__ import annotations

import errno
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from app.commands.cli import main
from app.errors import InputError
from app.formats.files import write_bytes
from tests.app.conftest import Cli


def one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


def edited(src: Path, dst: Path, line: int, column: int, value: str) -> Path:
    rows = src.read_text().splitlines()
    cells = rows[line - 1].split(",")
    cells[column] = value
    rows[line - 1] = ",".join(cells)
    dst.write_text("\n".join(rows) + "\n")
    return dst


def identify(simdir: Path, out: Path, meas: Path | None = None, *extra: str) -> list[str]:
    return [
        "identify",
        "--targets",
        str(simdir / "calibration_targets.csv"),
        "--measurements",
        str(meas or simdir / "calibration_measurements.csv"),
        "--out",
        str(out),
        *extra,
    ]


def test_a_gross_error_fails_the_gates_and_writes_nothing(
    simdir: Path, tmp_path: Path, cli: Cli
) -> None:
    meas = edited(simdir / "calibration_measurements.csv", tmp_path / "m.csv", 5, 7, "505.0")
    out = tmp_path / "params.json"
    out.write_text("previous version\n")
    kept = tmp_path / "failed.json"
    code, _, err = cli(identify(simdir, out, meas, "--keep-failed", str(kept)))
    line = one_line(err)
    assert code == 3 and "calibration rejected: residual RMS" in line
    assert f"{meas}:5" in line  # the worst measurement's line
    assert out.read_text() == "previous version\n"
    doc = json.loads(kept.read_text())
    assert doc["success"] is False and doc["converged"] is True
    assert any("max_rms_mm" in f for f in doc["gates"]["failures"])
    # a failed parameters file is refused by every reader unless asked for
    val = ["--targets", str(simdir / "validation_targets.csv")]
    val += ["--measurements", str(simdir / "validation_measurements.csv")]
    code, _, err = cli(["validate", "--params", str(kept), *val])
    assert code == 2 and "field 'success': a failed identification" in one_line(err)
    code, _, err = cli(["observability", "--params", str(kept), "--measurements", str(meas)])
    assert code == 2 and "failed identification" in err
    assert cli(["validate", "--params", str(kept), "--allow-failed", *val])[0] == 0


def test_a_good_identification_passes_its_gates(simdir: Path, tmp_path: Path, cli: Cli) -> None:
    out = tmp_path / "params.json"
    code, text, _ = cli([*identify(simdir, out), "--json"])
    doc = json.loads(text)
    assert code == 0 and doc["success"] and doc["gates"] == {"passed": True, "failures": []}
    written = json.loads(out.read_text())
    assert written["provenance"]["rvis_version"] and written["provenance"]["command_line"]
    assert b"\r\n" not in (simdir / "calibration_measurements.csv").read_bytes()


@pytest.mark.parametrize("rotation_deg", [90.0, 180.0, -135.0])
def test_any_part_base_guess_converges(
    simdir: Path, tmp_path: Path, cli: Cli, rotation_deg: float
) -> None:
    """The cell file's part->base orientation is off by a large rotation: the closed-form
    alignment brings LM to the same solution as from the right guess."""
    cell = tmp_path / "cell.toml"
    cell.write_text(f"[frames]\npart_base_rotvec_deg = [0.0, 0.0, {90.0 + rotation_deg}]\n")
    code, text, _ = cli([*identify(simdir, tmp_path / "p.json"), "--cell", str(cell), "--json"])
    ref_code, ref_text, _ = cli([*identify(simdir, tmp_path / "ref.json"), "--json"])
    assert code == ref_code == 0
    rms, ref = json.loads(text)["residuals"]["rms_mm"], json.loads(ref_text)["residuals"]["rms_mm"]
    assert rms == pytest.approx(ref, rel=1e-6)


@pytest.mark.parametrize(
    ("line", "column", "value", "message"),
    [
        (2, 7, "1e300", "field 'sx_mm': 1e+300 mm is beyond +-100000 mm"),
        (3, 1, "nan", "field 'j1_deg': 'nan' is not a finite number"),
        (4, 2, "900", "field 'j2_deg': 900 deg is beyond +-720 deg"),
    ],
)
def test_magnitudes_in_csv(
    simdir: Path,
    tmp_path: Path,
    cli: Cli,
    line: int,
    column: int,
    value: str,
    message: str,
) -> None:
    meas = edited(simdir / "calibration_measurements.csv", tmp_path / "m.csv", line, column, value)
    code, _, err = cli(identify(simdir, tmp_path / "p.json", meas))
    assert code == 2 and f"m.csv:{line}: {message}" in one_line(err)


def test_target_coordinate_1e300(simdir: Path, tmp_path: Path, cli: Cli) -> None:
    targets = edited(simdir / "calibration_targets.csv", tmp_path / "t.csv", 2, 1, "1e300")
    argv = identify(simdir, tmp_path / "p.json")
    argv[argv.index("--targets") + 1] = str(targets)
    code, _, err = cli(argv)
    assert code == 2 and "t.csv:2: field 'x_mm': 1e+300 mm is beyond" in one_line(err)
    assert not (tmp_path / "p.json").exists()


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[simulation]\ntemp_c = nan\n", "cell.toml:2: [simulation] temp_c: expected a finite"),
        ("[frames]\npart_base_xyz_mm = [1, 2, inf]\n", "cell.toml:2: [frames] part_base_xyz_mm"),
        ("[simulation]\nseed = -3\n", "cell.toml:2: [simulation] seed: must be >= 0"),
        ("[robot]\nmodel = 3\n", "cell.toml:2: [robot] model: expected a string"),
        ('[robot]\nmodel = "kuka"\n', "[robot] model: expected one of fanuc-m710ic50"),
        ("[calibration]\nloss = 1\n", "[calibration] loss: expected a string"),
        (
            '[service]\nschedule = "adaptive"\nestimator = "batch"\n',
            "[service] schedule: adaptive scheduling needs",
        ),
        ("[planning]\nswarm_sise = 3\n", "unknown key (did you mean 'swarm_size'?)"),
        ("[servce]\n", "cell.toml:1: [servce]: unknown section (did you mean 'service'?)"),
        ("[sensor]\nstandoff_mm = -1.0\n", "[sensor] standoff_mm: must be > 0"),
        ("[simulation]\ncompliance = 1\n", "[simulation] compliance: expected true or false"),
        ("\n[calibration]\nmax_rms_mm = 0.2\nmax_rms_mm = 0.3\n", "cell.toml:4: invalid TOML"),
        ('[devices]\nplc = "rmi://x:1"\n', "[devices] plc: no plc backend for rmi://"),
        ('[service]\nstate_dir = "\xff"\n', "cell.toml:2: not UTF-8"),
    ],
)
def test_bad_cell_file(simdir: Path, tmp_path: Path, cli: Cli, text: str, message: str) -> None:
    cell = tmp_path / "cell.toml"
    cell.write_bytes(text.encode("latin-1"))
    code, _, err = cli([*identify(simdir, tmp_path / "p.json"), "--cell", str(cell)])
    assert code == 2 and message in one_line(err)
    code, _, err = cli(["simulate", "--out", str(tmp_path / "s"), "--cell", str(cell)])
    assert code == 2 and message in one_line(err)
    assert not (tmp_path / "s").exists()


def test_bom_accepted_by_every_reader(simdir: Path, tmp_path: Path, cli: Cli) -> None:
    bom = b"\xef\xbb\xbf"
    cell = tmp_path / "cell.toml"
    cell.write_bytes(bom + b"[calibration]\nmax_rms_mm = 0.3\n")
    meas = tmp_path / "m.csv"
    meas.write_bytes(bom + (simdir / "calibration_measurements.csv").read_bytes())
    out = tmp_path / "p.json"
    assert cli([*identify(simdir, out, meas), "--cell", str(cell)])[0] == 0
    out.write_bytes(bom + out.read_bytes())
    assert cli(["observability", "--params", str(out), "--measurements", str(meas)])[0] == 0


def test_simulate_names_an_unreachable_sphere(tmp_path: Path, cli: Cli) -> None:
    cell = tmp_path / "cell.toml"
    cell.write_text('[spheres]\nframe = "base"\npositions_mm = { P1 = [5000.0, 0.0, 0.0] }\n')
    code, _, err = cli(["simulate", "--out", str(tmp_path / "s"), "--cell", str(cell)])
    assert code == 2 and "too few views reach sphere P1 (0 of 6)" in one_line(err)
    assert not (tmp_path / "s").exists()


def test_validation_sampling_is_bounded(tmp_path: Path, cli: Cli) -> None:
    cell = tmp_path / "cell.toml"
    cell.write_text(
        "[base_plate]\nx_min_mm = -5000.0\nx_max_mm = 5000.0\ny_min_mm = -5000.0\n"
        "y_max_mm = 5000.0\n[planning]\nplate_margin_mm = 0.0\n"
    )
    code, _, err = cli(["simulate", "--out", str(tmp_path / "s"), "--cell", str(cell)])
    assert code == 2 and "[base_plate]" in one_line(err)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["simulate", "--out", "x", "--validation", "0"], "argument --validation: must be >= 1"),
        (["simulate", "--out", "x", "--seed", "-1"], "argument --seed: must be >= 0"),
        (["plan", "--out", "x.json", "--swarm", "1"], "field '--swarm': must be >= 2"),
        (["sensor", "calibrate", ".", "--out", "s.toml", "--square-mm", "0"], "--square-mm"),
        (["demo", "--seed", "x"], "argument --seed: 'x' is not an integer"),
    ],
)
def test_bad_options(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    argv: list[str],
    message: str,
) -> None:
    monkeypatch.chdir(tmp_path)
    try:
        code = main(argv)
    except SystemExit as exc:
        code = int(exc.code or 0)
    err = capsys.readouterr().err
    assert code == 2 and message in one_line(err) and "Traceback" not in err


@pytest.mark.parametrize("kind", ["directory", "under a file"])
def test_bad_output_paths(simdir: Path, tmp_path: Path, cli: Cli, kind: str) -> None:
    (tmp_path / "file").write_text("x")
    out = tmp_path if kind == "directory" else tmp_path / "file" / "p.json"
    code, text, err = cli(identify(simdir, out))
    reason = "is a directory" if kind == "directory" else "a parent of this path is a file"
    assert code == 2 and reason in one_line(err) and str(out) in err
    assert text == ""  # refused before any work


def test_a_failed_write_leaves_the_old_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A full disk during the write: InputError naming the path, the old content intact and no
    temporary file left behind."""
    path = tmp_path / "params.json"
    path.write_text("old\n")

    def full(fd: int) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(InputError, match="no space left on the device"):
        write_bytes(path, b"new\n")
    assert path.read_text() == "old\n" and [p.name for p in tmp_path.iterdir()] == ["params.json"]


def test_cli_startup_and_pipes(tmp_path: Path) -> None:
    """`rvis --help` loads no numerical library; `--version`; a closed pipe is no traceback."""
    probe = (
        "import sys; from app.commands.cli import main\n"
        "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
        "heavy = [m for m in ('numpy', 'cv2', 'scipy', 'fakes') if m in sys.modules]\n"
        "print('HEAVY', heavy)"
    )
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert "HEAVY []" in out.stdout
    rvis = [sys.executable, "-m", "app"]
    version = subprocess.run([*rvis, "--version"], capture_output=True, text=True, check=True)
    assert version.stdout.startswith("rvis ")
    proc = subprocess.Popen([*rvis, "--help"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.close()  # the reader went away before rvis wrote
    err = proc.stderr.read().decode()
    proc.wait(timeout=30)
    proc.stderr.close()
    assert "Traceback" not in err and "BrokenPipe" not in err


def test_experiment_maintenance_refuses_a_sphere_it_cannot_replace(
    tmp_path: Path, cli: Cli
) -> None:
    for event, sphere in (("axis", "P2"), ("fixture", "P9")):
        out = tmp_path / f"{event}-{sphere}"
        args = ["experiment", "maintenance", "--event", event, "--sphere", sphere]
        code, _, err = cli([*args, "--out", str(out)])
        assert code == 2 and "--sphere" in one_line(err) and "P1, P2, P3, P4" in err
        assert not out.exists()  # nothing made for a refused run
    # the part frame moved by a renewal: the whole fixture's, nothing else
    for extra in (
        ["--event", "sensor", "--frame"],
        ["--event", "fixture", "--sphere", "P2", "--frame"],
    ):
        out = tmp_path / "frame"
        code, _, err = cli(["experiment", "maintenance", *extra, "--out", str(out)])
        assert code == 2 and "--frame" in one_line(err) and not out.exists()
