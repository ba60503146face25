"""The SCPI DAC fake is a conforming SCPI / IEEE 488.2 instrument: header forms, compound
messages, the mandatory common commands and the standard error numbers, over its pty."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
import serial

from fakes._scpi import QUEUE_SIZE
from fakes.scpi_dac import IDN, ScpiDac


class Client:
    """A bare pyserial client: one program message out, one response message back."""

    def __init__(self, port: str) -> None:
        self.serial = serial.Serial(port, timeout=0.5)

    def send(self, message: str) -> None:
        self.serial.write(message.encode() + b"\n")

    def ask(self, message: str) -> str:
        self.send(message)
        line = self.serial.readline()
        assert line.endswith(b"\n"), f"no answer to {message!r}"
        return line.decode().strip()

    def error(self) -> int:
        return int(self.ask("SYST:ERR?").split(",")[0])


@pytest.fixture
def dac() -> Iterator[ScpiDac]:
    with ScpiDac() as d:
        yield d


@pytest.fixture
def client(dac: ScpiDac) -> Iterator[Client]:
    c = Client(dac.port)
    yield c
    c.serial.close()


@pytest.mark.parametrize(
    ("message", "volts"),
    [
        ("SOUR:VOLT 1.5", 1.5),
        ("source:voltage 1.5", 1.5),
        (":SOURce:VOLTage:LEVel:IMMediate:AMPLitude 1.5", 1.5),
        ("VOLT 1.5", 1.5),  # [:SOURce] is optional
        (":sour:volt:lev +15E-1", 1.5),
        ("SOUR:VOLT\t250 mV", 0.25),
        ("SOUR:VOLT -2V", -2.0),
        ("SOUR:VOLT MAX", 10.0),
        ("SOUR:VOLT min", -10.0),
    ],
)
def test_long_short_forms_case_and_leading_colon(
    client: Client, dac: ScpiDac, message: str, volts: float
) -> None:
    client.send(message)
    assert client.error() == 0
    assert dac.volts == pytest.approx(volts)
    assert float(client.ask("Source:Voltage?")) == pytest.approx(volts)


@pytest.mark.parametrize(
    ("message", "code"),
    [
        ("SOURC:VOLT 1", -113),  # neither the short nor the long form
        ("SOUR:VOLTAGES 1", -113),
        ("SOUR:FREQ 1", -113),
        ("SOUR:VOLT", -109),  # missing parameter
        ("SOUR:VOLT abc", -104),  # not a number
        ("SOUR:VOLT 1,2", -108),
        ("SOUR:VOLT 10.5", -222),
        ("SOUR::VOLT 1", -102),
        ("*FOO", -113),
    ],
)
def test_errors_have_the_standard_numbers(
    client: Client, dac: ScpiDac, message: str, code: int
) -> None:
    client.send("SOUR:VOLT 0.5")
    client.send(message)
    assert client.error() == code
    assert client.error() == 0
    assert dac.volts == pytest.approx(0.5)  # a rejected command changes nothing


def test_compound_messages_keep_the_header_path(client: Client, dac: ScpiDac) -> None:
    assert float(client.ask("SOUR:VOLT 2;VOLT?")) == pytest.approx(2.0)  # VOLT under SOUR
    assert client.ask(":SOUR:VOLT 3;:SYST:ERR?") == '0,"No error"'
    idn, opc = client.ask("*IDN?;*OPC?").split(";")
    assert (idn, opc) == (IDN, "1")
    assert client.ask("SYST:VERS?;ERR?") == '1999.0;0,"No error"'  # ERR under SYST
    client.send("SOUR:VOLT 4;FOO 1;VOLT 5")  # the bad unit fails alone
    assert client.error() == -113 and dac.volts == pytest.approx(5.0)


def test_common_commands(client: Client, dac: ScpiDac) -> None:
    assert client.ask("*IDN?") == IDN
    assert client.ask("*OPC?") == "1"
    assert client.ask("*ESR?") == "0"
    client.send("SOUR:VOLT 99")  # execution error: ESR bit 4
    client.send("BOGUS")  # command error: ESR bit 5
    assert int(client.ask("*STB?")) & 0x04  # error/event queue not empty
    assert client.ask("*ESR?") == str(0x10 | 0x20)
    assert client.ask("*ESR?") == "0"  # reading clears it
    client.send("*OPC")
    assert client.ask("*ESR?") == "1"
    client.send("SOUR:VOLT 3")
    client.send("*RST")
    assert client.ask("*OPC?") == "1"  # the DAC has executed *RST (was a race: seen failing)
    assert dac.volts == 0.0
    client.send("NOPE")
    client.send("*CLS")  # clears the queue and the event register
    assert client.ask("SYST:ERR?") == '0,"No error"'
    assert client.ask("*ESR?") == "0"
    client.send("*ESE 32")
    assert client.ask("*ESE?") == "32"
    client.send("*ESE")
    assert client.error() == -109
    assert client.ask("*TST?") == "0"


def test_the_error_queue_overflows_into_350(client: Client) -> None:
    for _ in range(QUEUE_SIZE + 3):
        client.send("BOGUS")
    codes = [client.error() for _ in range(QUEUE_SIZE + 1)]
    assert codes[: QUEUE_SIZE - 1] == [-113] * (QUEUE_SIZE - 1)
    assert codes[QUEUE_SIZE - 1 :] == [-350, 0]


def test_a_failing_query_answers_nothing(client: Client) -> None:
    client.send("*IDN? 1")
    assert client.ask("*OPC?") == "1"  # the next answer is the next query's, not garbage
    assert client.error() == -108
