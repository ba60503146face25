"""Settings: the cell file's [service], [line] and [calibration] keys reach the service."""

from __future__ import annotations

from pathlib import Path

import pytest

from app.config import load_cell
from app.line.settings import LineSettings, RecalibSettings, from_cell


def test_from_cell_reads_the_sections(tmp_path: Path) -> None:
    cell = tmp_path / "cell.toml"
    cell.write_text(
        '[service]\nmode = "approve"\nrolling_size = 30\nholdout_size = 6\nraw_sweeps_keep = 5\n'
        "[line]\noverride_pct = 50\npoll_s = 0.02\n[calibration]\nmax_rms_mm = 0.1\n",
        encoding="utf-8",
    )
    s = from_cell(load_cell(cell), tmp_path / "state")
    assert s.state_dir == tmp_path / "state" and s.raw_sweeps_keep == 5
    assert (s.recalib.mode, s.recalib.rolling_size, s.recalib.holdout_size) == ("approve", 30, 6)
    assert (s.line.override_pct, s.line.poll_s) == (50, 0.02)
    assert s.gates.max_rms_mm == 0.1
    assert from_cell(load_cell(None)).state_dir == Path("rvis-state")


def test_settings_refuse_nonsense() -> None:
    with pytest.raises(ValueError):
        LineSettings(override_pct=0)
    with pytest.raises(ValueError):
        RecalibSettings(mode="sometimes")  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        RecalibSettings(rolling_size=5)


def test_opcua_settings_are_the_cell_files(tmp_path: Path) -> None:
    """[opcua] reaches the service; the settings' defaults are the cell file's."""
    from dataclasses import asdict

    from app.config import OpcUaSection
    from app.line.settings import OpcUaSettings

    assert asdict(OpcUaSettings()) == dict(OpcUaSection())
    cell = tmp_path / "cell.toml"
    cell.write_text(
        '[opcua]\nenabled = true\nendpoint = "opc.tcp://0.0.0.0:4841/x"\n'
        'security_policy = "Aes256Sha256RsaPss"\nallow_ack = true\n',
        encoding="utf-8",
    )
    s = from_cell(load_cell(cell), tmp_path / "state").opcua
    assert (s.enabled, s.endpoint, s.security_policy, s.allow_ack) == (
        True,
        "opc.tcp://0.0.0.0:4841/x",
        "Aes256Sha256RsaPss",
        True,
    )
