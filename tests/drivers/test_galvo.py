"""Galvo contract (fake:// and the SCPI DAC behind a pty) and SCPI fault tests."""

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
from drivers.galvo import Galvo, GalvoCalibration
from drivers.scpi_galvo import ScpiGalvo
from fakes.scpi_dac import ScpiDac

CAL = GalvoCalibration(coefficients=(0.1, 0.45, 0.002), angle_limits_deg=(-15.0, 15.0))


@pytest.fixture(params=["fake", "scpi"])
def galvo(request: pytest.FixtureRequest) -> Iterator[Galvo]:
    with ExitStack() as stack:
        if request.param == "fake":
            url = "fake://"
        else:
            dac = stack.enter_context(ScpiDac())
            url = f"scpi+serial://{dac.port}?baud=115200"
        yield stack.enter_context(open_galvo(url, calibration=CAL, timeout_s=0.3))


def test_angle_round_trip(galvo: Galvo) -> None:
    for angle in (-15.0, -3.25, 0.0, 7.5, 15.0):
        volts = galvo.set_angle_deg(angle)
        assert volts == pytest.approx(CAL.angle_to_volts(angle))
        assert galvo.angle_deg() == pytest.approx(angle, abs=1e-4)
    assert galvo.describe()


def test_angles_outside_the_limits_are_refused(galvo: Galvo) -> None:
    galvo.set_angle_deg(1.0)
    for bad in (15.01, -40.0, float("nan")):
        with pytest.raises(MotionRefused):
            galvo.set_angle_deg(bad)
    assert galvo.angle_deg() == pytest.approx(1.0, abs=1e-4)


@given(st.floats(-15, 15))
def test_calibration_inverse(angle: float) -> None:
    assert CAL.volts_to_angle(CAL.angle_to_volts(angle)) == pytest.approx(angle, abs=1e-7)


def test_non_monotonic_calibration_is_rejected() -> None:
    with pytest.raises(DeviceConfigError, match="monotonic"):
        GalvoCalibration(coefficients=(0.0, 0.1, 0.05), angle_limits_deg=(-10, 10))


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
        scpi.set_angle_deg(2.0)
    assert info.value.code == -222
    scpi.set_angle_deg(2.0)
    assert dac.volts == pytest.approx(1.0)


def test_out_of_range_voltage_reported_by_the_board(dac: ScpiDac) -> None:
    wide = GalvoCalibration(
        coefficients=(0.0, 0.5), angle_limits_deg=(-22, 22), volt_limits=(-12, 12)
    )
    with (
        ScpiGalvo(dac.port, calibration=wide, timeout_s=0.2) as g,
        pytest.raises(DeviceFault, match="out of range"),
    ):
        g.set_angle_deg(21.0)


def test_silence_is_a_timeout_and_retried(dac: ScpiDac, scpi: ScpiGalvo) -> None:
    dac.fail_next("SOUR:VOLT?", "mute")
    with pytest.raises(DeviceTimeout):
        scpi._get_volts()
    dac.fail_next("SOUR:VOLT?", "mute")
    assert scpi.angle_deg() == pytest.approx(0.0)  # reopened and asked again


@pytest.mark.parametrize("mode", ["garble", "truncate"])
def test_bad_answers_are_protocol_errors(dac: ScpiDac, scpi: ScpiGalvo, mode: str) -> None:
    dac.fail_next("SOUR:VOLT?", mode)
    with pytest.raises(ProtocolError):
        scpi._get_volts()


def _operation(galvo: ScpiGalvo, command: str) -> Callable[[], float]:
    """The public call that sends ``command``: a read-back, or a set (SOUR:VOLT + SYST:ERR?)."""
    if command == "SOUR:VOLT?":
        return galvo.angle_deg
    return lambda: galvo.set_angle_deg(3.0)


@pytest.mark.parametrize("command", ["SOUR:VOLT?", "SOUR:VOLT", "SYST:ERR?", "between commands"])
def test_board_vanishing_is_a_connection_error_until_it_is_back(
    tmp_path: Path, command: str
) -> None:
    with ScpiDac(link=tmp_path / "ttyDAC") as dac, ScpiGalvo(dac.port, timeout_s=0.2) as galvo:
        galvo.set_angle_deg(2.0)
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
        assert galvo.set_angle_deg(3.0) == pytest.approx(1.5)
        assert dac.volts == pytest.approx(1.5) and galvo.angle_deg() == pytest.approx(3.0)
