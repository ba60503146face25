"""Galvo contract: one test body per behaviour, run on fake://, the SCPI DAC behind a pty and a
real DAC (``RVIS_GALVO_URL``, commanded only within ``RVIS_GALVO_VOLTS``); then the SCPI fault
tests, which need the peer."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import ExitStack
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers import (
    DeviceConnectionError,
    DeviceFault,
    DeviceTimeout,
    MotionRefused,
    ProtocolError,
    open_galvo,
)
from drivers.errors import DeviceConfigError
from drivers.galvo import Galvo, GalvoSettings
from drivers.scpi_galvo import ScpiGalvo
from fakes.scpi_dac import ScpiDac
from tests.drivers.backends import HARDWARE, backends, galvo_volts, real_url


@pytest.fixture(params=backends("galvo", ["fake", "scpi"]))
def backend(request: pytest.FixtureRequest) -> str:
    return str(request.param)


@pytest.fixture
def tol_v(backend: str) -> float:
    """Read-back tolerance [V]: exact on the fakes, a 12-bit DAC's step on a real one."""
    lo, hi = galvo_volts()
    return (hi - lo) / 4096 if backend == HARDWARE else 1e-6


@pytest.fixture
def galvo(backend: str) -> Iterator[Galvo]:
    limits = GalvoSettings(*galvo_volts())
    with ExitStack() as stack:
        if backend == HARDWARE:
            url = real_url("galvo")
        elif backend == "fake":
            url = "fake://"
        else:
            dac = stack.enter_context(ScpiDac())
            url = f"scpi+serial://{dac.port}?baud=115200"
        device = stack.enter_context(open_galvo(url, settings=limits, timeout_s=0.5))
        stack.callback(_park, device)
        yield device


def _park(galvo: Galvo) -> None:
    """Leave the mirror at the middle of the range (0 V when the range holds it)."""
    if galvo.is_open:
        lo, hi = galvo.settings.volt_min, galvo.settings.volt_max
        galvo.set_volts(min(max(0.0, lo), hi))


def test_volts_round_trip(galvo: Galvo, tol_v: float) -> None:
    lo, hi = galvo.settings.volt_min, galvo.settings.volt_max
    for command_v in (lo, lo + 0.2833 * (hi - lo), (lo + hi) / 2, lo + 0.7345678 * (hi - lo), hi):
        assert galvo.set_volts(command_v) == command_v
        assert galvo.volts() == pytest.approx(command_v, abs=tol_v)
    assert galvo.describe()


def test_commands_outside_the_limits_are_refused(galvo: Galvo, tol_v: float) -> None:
    lo, hi = galvo.settings.volt_min, galvo.settings.volt_max
    middle = (lo + hi) / 2
    galvo.set_volts(middle)
    for bad in (hi + 0.01, lo - 32.5, float("nan"), float("inf")):
        with pytest.raises(MotionRefused):
            galvo.set_volts(bad)
    assert galvo.volts() == pytest.approx(middle, abs=tol_v)


@given(st.floats(-20, 20), st.floats(-20, 20))
def test_settings_need_an_ordered_range(lo: float, hi: float) -> None:
    if lo < hi:
        assert GalvoSettings(lo, hi).volt_max == hi
    else:
        with pytest.raises(DeviceConfigError):
            GalvoSettings(lo, hi)


@pytest.fixture
def dac() -> Iterator[ScpiDac]:
    with ScpiDac() as d:
        yield d


@pytest.fixture
def scpi(dac: ScpiDac) -> Iterator[ScpiGalvo]:
    with ScpiGalvo(dac.port, timeout_s=0.2) as g:
        yield g


def test_error_from_the_board_is_a_device_fault(dac: ScpiDac, scpi: ScpiGalvo) -> None:
    dac.fail_next("SOUR:VOLT", -222)
    with pytest.raises(DeviceFault, match="-222") as info:
        scpi.set_volts(1.0)
    assert info.value.code == -222
    assert dac.volts == 0.0  # not executed
    scpi.set_volts(1.0)
    assert dac.volts == pytest.approx(1.0)


def test_out_of_range_voltage_reported_by_the_board(dac: ScpiDac) -> None:
    wide = GalvoSettings(volt_min=-12.0, volt_max=12.0)
    with ScpiGalvo(dac.port, settings=wide, timeout_s=0.2) as g:
        g.set_volts(2.0)
        with pytest.raises(DeviceFault, match="out of range") as info:
            g.set_volts(11.0)
        assert info.value.code == -222
        assert dac.volts == pytest.approx(2.0)  # the board kept its output


def test_silence_is_a_timeout_and_retried(dac: ScpiDac, scpi: ScpiGalvo) -> None:
    dac.fail_next("SOUR:VOLT?", "mute")
    with pytest.raises(DeviceTimeout):
        scpi._get_volts()
    dac.fail_next("SOUR:VOLT?", "mute")
    assert scpi.volts() == pytest.approx(0.0)  # reopened and asked again


@pytest.mark.parametrize("mode", ["garble", "truncate"])
def test_bad_answers_are_protocol_errors(dac: ScpiDac, scpi: ScpiGalvo, mode: str) -> None:
    dac.fail_next("SOUR:VOLT?", mode)
    with pytest.raises(ProtocolError):
        scpi._get_volts()


def _operation(galvo: ScpiGalvo, command: str) -> Callable[[], float]:
    """The public call that sends ``command``: a read-back, or a set (SOUR:VOLT + SYST:ERR?)."""
    if command == "SOUR:VOLT?":
        return galvo.volts
    return lambda: galvo.set_volts(1.5)


@pytest.mark.parametrize("command", ["SOUR:VOLT?", "SOUR:VOLT", "SYST:ERR?", "between commands"])
def test_board_vanishing_is_a_connection_error_until_it_is_back(
    tmp_path: Path, command: str
) -> None:
    with ScpiDac(link=tmp_path / "ttyDAC") as dac, ScpiGalvo(dac.port, timeout_s=0.2) as galvo:
        galvo.set_volts(1.0)
        if command == "between commands":
            dac.unplug()
            command = "SOUR:VOLT"
        else:
            dac.fail_next(command, "drop")  # the pty closes while the driver waits for it
        operation = _operation(galvo, command)
        with pytest.raises(DeviceConnectionError):
            operation()  # the retry's reconnect finds no port either
        assert not dac.plugged and galvo.is_open
        with pytest.raises(DeviceConnectionError):
            operation()  # still typed, still no hang
        dac.replug()  # back under the same name: the next call reconnects
        assert galvo.set_volts(1.5) == pytest.approx(1.5)
        assert dac.volts == pytest.approx(1.5) and galvo.volts() == pytest.approx(1.5)
