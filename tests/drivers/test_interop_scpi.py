"""SCPI interop:

- pyvisa + pyvisa-py (a serial INSTR resource on the pty) against our SCPI DAC peer;
- our galvo driver against a small SCPI instrument written from SCPI-99 / IEEE 488.2 alone (no
  code of our peer): it makes other legal choices (``+0,"No error"``, NR3 answers with a sign, CR LF
  response terminators, ``SOURce`` not optional, error text without quotes would also be legal).
"""

from __future__ import annotations

import os
import re
import select
import threading
import tty
from collections.abc import Iterator

import pytest
import pyvisa

from drivers import DeviceFault
from drivers.scpi_galvo import ScpiGalvo
from fakes.scpi_dac import IDN, ScpiDac


@pytest.fixture
def visa_dac() -> Iterator[tuple[pyvisa.resources.MessageBasedResource, ScpiDac]]:
    with ScpiDac() as dac:
        rm = pyvisa.ResourceManager("@py")
        inst = rm.open_resource(
            f"ASRL{dac.port}::INSTR",
            read_termination="\n",
            write_termination="\n",
            timeout=1000,
        )
        assert isinstance(inst, pyvisa.resources.MessageBasedResource)
        try:
            yield inst, dac
        finally:
            inst.close()
            rm.close()


def test_pyvisa_identifies_sets_and_reads_back(
    visa_dac: tuple[pyvisa.resources.MessageBasedResource, ScpiDac],
) -> None:
    inst, dac = visa_dac
    assert inst.query("*IDN?") == IDN
    inst.write("*CLS")
    inst.write("source:voltage 2.5")
    assert inst.query("*OPC?") == "1"  # the instrument has executed what came before
    assert dac.volts == pytest.approx(2.5)
    assert inst.query_ascii_values("SOUR:VOLT?") == [pytest.approx(2.5)]
    assert inst.query("SYST:ERR?") == '0,"No error"'


def test_pyvisa_sees_the_standard_errors(
    visa_dac: tuple[pyvisa.resources.MessageBasedResource, ScpiDac],
) -> None:
    inst, dac = visa_dac
    inst.write("VOLT 22")
    assert inst.query("*ESR?") == "16"  # execution error
    assert inst.query("SYST:ERR?") == '-222,"Data out of range"'
    inst.write("VOLT")
    assert inst.query("SYST:ERR?") == '-109,"Missing parameter"'
    assert dac.volts == 0.0


class StandardInstrument:
    """A DAC written from SCPI-99 and IEEE 488.2 only, behind its own pty."""

    _VOLT = re.compile(r"^:?SOUR(?:CE)?:VOLT(?:AGE)?(\?)?(?:\s+(\S+))?$", re.IGNORECASE)
    _ERR = re.compile(r"^:?SYST(?:EM)?:ERR(?:OR)?(?::NEXT)?\?$", re.IGNORECASE)

    def __init__(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.port = os.ttyname(self.slave)
        self.volts = 0.0
        self.errors: list[str] = []
        self.heard: list[str] = []
        self._stop_r, self._stop_w = os.pipe()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def close(self) -> None:
        os.write(self._stop_w, b"x")
        self._thread.join(2.0)
        for fd in (self.master, self.slave, self._stop_r, self._stop_w):
            os.close(fd)

    def _serve(self) -> None:
        buf = b""
        while True:
            ready, _, _ = select.select([self.master, self._stop_r], [], [])
            if self._stop_r in ready:
                return
            buf += os.read(self.master, 1024)
            while b"\n" in buf:
                line, buf = buf.split(b"\n", 1)
                answer = self._message(line.decode().strip())
                if answer is not None:
                    os.write(self.master, answer.encode() + b"\r\n")

    def _message(self, text: str) -> str | None:
        self.heard.append(text)
        if text.upper() == "*IDN?":
            return "ACME INSTRUMENTS,DAC-2,SN42,2.0.1"
        if text.upper() == "*CLS":
            self.errors.clear()
            return None
        if self._ERR.match(text):
            return self.errors.pop(0) if self.errors else '+0,"No error"'
        volt = self._VOLT.match(text)
        if volt is None:
            self.errors.append('-113,"Undefined header"')
            return None
        if volt.group(1):
            return f"{self.volts:+.8E}"
        value = float(volt.group(2))
        if abs(value) > 5.0:
            self.errors.append('-222,"Data out of range;limit 5 V"')
        else:
            self.volts = value
        return None


@pytest.fixture
def standard() -> Iterator[StandardInstrument]:
    inst = StandardInstrument()
    yield inst
    inst.close()


def test_our_driver_works_with_another_conforming_instrument(standard: StandardInstrument) -> None:
    with ScpiGalvo(standard.port, timeout_s=0.5) as galvo:
        assert galvo.describe() == "ACME INSTRUMENTS,DAC-2,SN42,2.0.1"
        assert galvo.set_volts(-1.25) == -1.25
        assert standard.volts == -1.25
        assert galvo.volts() == pytest.approx(-1.25)
        with pytest.raises(DeviceFault, match="out of range") as info:
            galvo.set_volts(7.0)
        assert info.value.code == -222 and standard.volts == -1.25
    assert standard.heard[0] == "*CLS"
