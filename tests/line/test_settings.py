"""Settings: the cell file's [service], [line] and [calibration] keys reach the service; the
PLC's cell temperature is read only when the PLC provides it, and only when plausible."""

from __future__ import annotations

from pathlib import Path

import pytest

from app.config import load_cell
from app.config.line import LineSettings, RecalibSettings
from app.errors import InputError
from app.line.cycle import WindowWatch
from app.line.settings import from_cell
from drivers.clock import RealClock
from drivers.plc import NO_TEMPERATURE, WINDOW_OPEN, decode_inputs, encode_temp
from fakes.devices import FakePlc


def test_from_cell_reads_the_sections(tmp_path: Path) -> None:
    cell = tmp_path / "cell.toml"
    cell.write_text(
        '[service]\nmode = "approve"\nrolling_size = 30\nholdout_size = 6\nraw_sweeps_keep = 5\n'
        "[line]\noverride_pct = 50\npoll_s = 0.02\n[calibration]\nmax_rms_mm = 0.1\n",
        encoding="utf-8",
    )
    s = from_cell(load_cell(cell), tmp_path / "state")
    assert s.state_dir == tmp_path / "state" and s.ops.raw_sweeps_keep == 5
    assert (s.recalib.mode, s.recalib.rolling_size, s.recalib.holdout_size) == ("approve", 30, 6)
    assert (s.line.override_pct, s.line.poll_s) == (50, 0.02)
    assert s.gates.max_rms_mm == 0.1
    assert from_cell(load_cell(None)).state_dir == Path("rvis-state")


def test_settings_refuse_nonsense() -> None:
    with pytest.raises(ValueError):
        LineSettings(override_pct=0)
    with pytest.raises(ValueError):
        RecalibSettings(mode="sometimes")
    with pytest.raises(ValueError):
        RecalibSettings(rolling_size=5)


def test_opcua_settings_are_the_cell_files(tmp_path: Path) -> None:
    """[opcua] reaches the service."""
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


def test_the_plc_temperature_is_read_only_when_the_cell_file_says_the_plc_provides_it(
    tmp_path: Path,
) -> None:
    assert load_cell(None).line.plc_temperature is False  # off by default
    cell = tmp_path / "cell.toml"
    cell.write_text("[line]\nplc_temperature = true\nplc_temp_min_c = 10.0\n", encoding="utf-8")
    s = from_cell(load_cell(cell)).line
    assert (s.plc_temperature, s.plc_temp_min_c, s.plc_temp_max_c) == (True, 10.0, 50.0)
    cell.write_text("[line]\nplc_temp_min_c = 30.0\nplc_temp_max_c = 25.0\n", encoding="utf-8")
    with pytest.raises(InputError, match=r"cell.toml:3: \[line\] plc_temp_max_c"):
        load_cell(cell)
    with pytest.raises(ValueError):
        LineSettings(plc_temp_min_c=30.0, plc_temp_max_c=25.0)


def _watch(line: LineSettings, temp_word: int | None) -> WindowWatch:
    watch = WindowWatch(FakePlc(), RealClock(), line)
    words = (WINDOW_OPEN, 1) if temp_word is None else (WINDOW_OPEN, 1, temp_word)
    watch.inputs = decode_inputs(words)
    return watch


def test_an_implausible_or_missing_plc_temperature_is_none_with_the_reason() -> None:
    on = LineSettings(plc_temperature=True)
    assert _watch(LineSettings(), encode_temp(21.5)).temperature() == (None, "")  # not read
    assert _watch(on, encode_temp(21.5)).temperature() == (21.5, "")
    for word, why in (
        (0, "reads 0.00 degC, outside [line] plc_temp_min_c..plc_temp_max_c = 5..50"),
        (encode_temp(61.0), "reads 61.00 degC"),
        (encode_temp(-3.0), "reads -3.00 degC"),
        (NO_TEMPERATURE, "no sensor (0x8000)"),
        (None, "no sensor (0x8000)"),  # a backend without the word
    ):
        temp_c, reason = _watch(on, word).temperature()
        assert temp_c is None and why in reason
