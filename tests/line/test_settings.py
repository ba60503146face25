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
from fakes.clock import VirtualClock
from fakes.devices import ClampCycle, FakePlc


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


def test_the_plc_body_id_is_off_unless_the_cell_file_names_its_format(tmp_path: Path) -> None:
    """`[line] plc_body_id`: "none" by default (the words are not read: a PLC program without
    them may not have the registers), "u32" or "serial8" from the cell file, nothing else."""
    assert load_cell(None).line.plc_body_id == "none"
    cell = tmp_path / "cell.toml"
    for fmt in ("u32", "serial8", "none"):
        cell.write_text(f'[line]\nplc_body_id = "{fmt}"\n', encoding="utf-8")
        assert from_cell(load_cell(cell)).line.plc_body_id == fmt
    cell.write_text('[line]\nplc_body_id = "u64"\n', encoding="utf-8")
    with pytest.raises(InputError, match=r"cell.toml:2: \[line\] plc_body_id.*u32, serial8"):
        load_cell(cell)
    with pytest.raises(ValueError):
        LineSettings(plc_body_id="vin17")


class _CountingPlc(FakePlc):
    """The fake PLC counting the requests for the body id words."""

    body_reads = 0

    def _read_body_words(self, count: int) -> tuple[int, ...]:
        self.body_reads += 1
        return super()._read_body_words(count)


def test_the_window_watch_reads_the_body_once_at_each_rising_edge_only_when_asked() -> None:
    """Each window the PLC opens queues (the clock's time, the clamped body's id), read once at
    its rising edge (a window open at the first reading counts); never with plc_body_id off."""
    cycle = ClampCycle(period_s=60.0, window_s=8.0, beat_s=0.5, first_body=700)
    for fmt, expected in (("u32", [701, 702]), ("serial8", ["B0000701", "B0000702"])):
        clock = VirtualClock(start_epoch=1000.0)
        plc = _CountingPlc(cycle, clock=clock)
        plc.body_format = fmt
        plc.open()
        watch = WindowWatch(plc, clock, LineSettings(plc_body_id=fmt))
        for t in (30.0, 113.0, 115.0, 119.9, 121.0, 173.0, 179.0):  # windows 1 and 2 open
            clock.advance(t - clock.monotonic())
            watch.poll()
        assert list(watch.clamped) == [(1113.0, expected[0]), (1173.0, expected[1])]
        assert plc.body_reads == 2  # once a window
        off = WindowWatch(plc, clock, LineSettings())
        clock.advance(60.0)
        off.poll()  # window 3 open at its first reading: not read, nothing queued
        assert not off.clamped and plc.body_reads == 2
        plc.close()
    # a window open at the first reading is a body too (the service started inside it)
    clock = VirtualClock(start_epoch=0.0)
    plc = _CountingPlc(cycle, clock=clock)
    plc.open()
    clock.advance(55.0)
    watch = WindowWatch(plc, clock, LineSettings(plc_body_id="u32"))
    watch.poll()
    assert list(watch.clamped) == [(55.0, 700)]
    plc.close()
