"""Modbus interop with an implementation other than pymodbus (pyModbusTCP 0.3.1):

- pyModbusTCP's client against our Modbus peers (the line PLC, the FANUC register mailbox): reads
  (FC3), single writes (FC6, whose reply pyModbusTCP checks is the request's echo), multiple
  writes (FC16), a whole mailbox motion;
- our PLC driver against a pyModbusTCP server holding the register map of drivers/plc_modbus.py,
  written from that table alone (no code of our peers).
"""

from __future__ import annotations

import socket
import time
from collections.abc import Iterator

import numpy as np
import pytest
from pyModbusTCP.client import ModbusClient
from pyModbusTCP.server import DataBank, ModbusServer
from pyModbusTCP.utils import decode_ieee, encode_ieee, long_list_to_word, word_list_to_long

from drivers import DeviceFault, DeviceTimeout, open_plc
from drivers.modbus_robot import MAILBOX, STATUS_IDLE
from fakes.devices import ClampCycle
from fakes.modbus_robot import ModbusRobotServer
from fakes.plc import PlcServer
from fakes.world import StaticWorld

CYCLE = ClampCycle(period_s=60.0, window_s=8.0, beat_s=0.5, time_scale=0.002)


def floats(words: list[int]) -> list[float]:
    """FANUC REALs, low word first (the mailbox's word order), decoded with pyModbusTCP."""
    return [decode_ieee(v) for v in word_list_to_long(words, big_endian=False)]


def words(values: list[float]) -> list[int]:
    return list(long_list_to_word([encode_ieee(v) for v in values], big_endian=False))


def client(port: int) -> ModbusClient:
    return ModbusClient(host="127.0.0.1", port=port, unit_id=1, timeout=2.0, auto_open=True)


def test_pymodbustcp_reads_and_writes_the_plc_peer() -> None:
    with PlcServer(CYCLE) as plc:
        c = client(plc.port)
        try:
            status, beat = c.read_holding_registers(0, 2)
            assert status & 0x2 and 0 <= beat <= 0xFFFF  # line running
            assert c.write_single_register(11, 1234)  # FC6: the reply must echo the request
            assert plc.received.heartbeat == 1234
            assert c.write_single_register(10, 0x1)  # busy
            assert plc.received.busy and not plc.received.done
            assert c.write_multiple_registers(10, [0x2, 1235])  # FC16: done + heartbeat
            assert plc.received.done and plc.received.heartbeat == 1235
            # a write to a PLC-owned word is echoed too (the next scan overwrites it)
            assert c.write_single_register(0, 0x7)
            assert c.read_holding_registers(0, 1)[0] in (0x2, 0x3)
        finally:
            c.close()


def test_pymodbustcp_drives_the_robot_mailbox(world: StaticWorld) -> None:
    target = [10.0, -5.0, 5.0, 0.0, -80.0, 20.0]
    with ModbusRobotServer(world, time_scale=0.002) as robot:
        c = client(robot.port)
        try:
            current = floats(c.read_holding_registers(MAILBOX.CURRENT, 12))
            np.testing.assert_allclose(current, world.joints_deg(), atol=1e-4)
            assert c.write_multiple_registers(MAILBOX.SPEED, words([100.0, *target]))
            assert c.write_multiple_registers(MAILBOX.CMD, words([1.0]))
            deadline = time.monotonic() + 2.0
            while floats(c.read_holding_registers(MAILBOX.DONE, 2))[0] != 1.0:
                assert time.monotonic() < deadline, "the TP never completed the motion"
            np.testing.assert_allclose(world.joints_deg(), target, atol=1e-4)
            status, error = floats(c.read_holding_registers(MAILBOX.STATUS, 4))
            assert (status, error) == (STATUS_IDLE, 0.0)
        finally:
            c.close()


class ThirdPartyPlc:
    """A line PLC on a pyModbusTCP server, from the register table of drivers/plc_modbus.py:
    word 0 status (bit 0 window, bit 1 line running), word 1 heartbeat, words 10-11 the app's."""

    def __init__(self) -> None:
        with socket.socket() as s:  # pyModbusTCP binds the port it is given: find a free one
            s.bind(("127.0.0.1", 0))
            self.port = s.getsockname()[1]
        self.bank = DataBank()
        self.server = ModbusServer("127.0.0.1", self.port, no_block=True, data_bank=self.bank)

    def __enter__(self) -> ThirdPartyPlc:
        self.server.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.server.stop()

    def set_plc(self, status: int, beat: int) -> None:
        self.bank.set_holding_registers(0, [status, beat])

    def app_words(self) -> list[int]:
        return list(self.bank.get_holding_registers(10, 2) or [])


@pytest.fixture
def third_party_plc() -> Iterator[ThirdPartyPlc]:
    with ThirdPartyPlc() as plc:
        yield plc


def test_our_plc_driver_against_a_pymodbustcp_server(third_party_plc: ThirdPartyPlc) -> None:
    peer = third_party_plc
    peer.set_plc(0x2, 1)  # line running, window closed
    opts = {"poll_s": 0.001, "heartbeat_timeout_s": 0.5, "timeout_s": 1.0}
    with open_plc(f"plc+modbus://127.0.0.1:{peer.port}", **opts) as plc:
        assert peer.app_words() == [0, 0]  # outputs reset on connect
        with pytest.raises(DeviceTimeout, match="window closed"):
            plc.wait_window(timeout_s=0.05)
        peer.set_plc(0x3, 2)  # the window opens, the heartbeat moves
        with plc.window(timeout_s=1.0) as inputs:
            assert inputs.window_open and inputs.heartbeat == 2
            assert peer.app_words()[0] == 0x1  # busy
        bits, beat = peer.app_words()
        assert bits == 0x2 and beat == plc.outputs.heartbeat > 0  # done, our heartbeat


def test_the_plc_peer_answers_only_its_unit_and_the_function_codes_of_its_map() -> None:
    """As a PLC's Modbus server: unit 1 (configurable), holding registers through FC3, FC6 and
    FC16; another function code is exception 1 (illegal function), another unit exception 11
    (gateway target device failed to respond). The peer answered any unit, and FC1 and FC4."""
    with PlcServer(CYCLE) as plc, PlcServer(CYCLE, unit=7) as plc7:
        c = client(plc.port)
        try:
            assert c.read_holding_registers(0, 3) is not None and c.last_except == 0
            assert c.write_single_register(11, 5) and c.write_multiple_registers(10, [0, 6])
            calls = {
                1: lambda: c.read_coils(0, 1),
                2: lambda: c.read_discrete_inputs(0, 1),
                4: lambda: c.read_input_registers(0, 3),
                5: lambda: c.write_single_coil(0, True),
                15: lambda: c.write_multiple_coils(0, [True]),
            }
            for fc, call in calls.items():
                assert call() in (None, False), fc
                assert c.last_except == 1, fc  # illegal function
        finally:
            c.close()
        for port, unit in ((plc.port, 2), (plc.port, 0), (plc7.port, 1)):
            other = ModbusClient(host="127.0.0.1", port=port, unit_id=unit, timeout=2.0)
            try:
                assert other.read_holding_registers(0, 3) is None
                assert other.last_except == 11, (port, unit)
            finally:
                other.close()
        seven = ModbusClient(host="127.0.0.1", port=plc7.port, unit_id=7, timeout=2.0)
        try:
            assert seven.read_holding_registers(0, 3) is not None
        finally:
            seven.close()


def test_our_plc_driver_names_the_unit_a_plc_does_not_answer() -> None:
    with PlcServer(CYCLE) as server:
        with pytest.raises(DeviceFault, match=r"\(unit 3\): exception 11: gateway target") as exc:
            open_plc(f"plc+modbus://127.0.0.1:{server.port}?unit=3", timeout_s=0.5)
        assert exc.value.code == 11
        with open_plc(f"plc+modbus://127.0.0.1:{server.port}?unit=1", timeout_s=0.5) as plc:
            assert plc.poll().line_running in (True, False)
