"""PLC contract (fake:// and the pymodbus PLC peer): the clamp-window handshake and heartbeat of
the base class, over each backend's register-level primitives."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import ExitStack
from typing import Any

import pytest

from drivers import DeviceConnectionError, DeviceFault, DeviceTimeout, open_plc
from drivers.plc import (
    BUSY,
    FAULT,
    LINE_RUNNING,
    NO_TEMPERATURE,
    WINDOW_OPEN,
    Plc,
    PlcInputs,
    PlcOutputs,
    decode_inputs,
    decode_outputs,
    decode_temp,
    encode_inputs,
    encode_outputs,
    encode_temp,
)
from fakes.devices import ClampCycle, FakePlc

# 60 s cycle with an 8 s window, compressed 500x: 120 ms period, 16 ms window, 1 ms beat
CYCLE = ClampCycle(period_s=60.0, window_s=8.0, beat_s=0.5, time_scale=0.002)
OPTS: dict[str, Any] = {"poll_s": 0.001, "heartbeat_timeout_s": 0.05, "timeout_s": 0.5}


def _open(kind: str, cycle: ClampCycle, stack: ExitStack) -> tuple[Plc, Any]:
    if kind == "fake":
        plc = stack.enter_context(open_plc("fake://", cycle=cycle, **OPTS))
        assert isinstance(plc, FakePlc)
        return plc, plc
    from fakes.plc import PlcServer

    server = stack.enter_context(PlcServer(cycle))
    return stack.enter_context(open_plc(f"plc+modbus://127.0.0.1:{server.port}", **OPTS)), server


@pytest.fixture(params=["fake", "modbus"])
def kind(request: pytest.FixtureRequest) -> str:
    return str(request.param)


@pytest.fixture
def plc_and_peer(kind: str) -> Iterator[tuple[Plc, Any]]:
    with ExitStack() as stack:
        yield _open(kind, CYCLE, stack)


def test_waits_for_the_window_and_signals_busy_then_done(plc_and_peer: tuple[Plc, Any]) -> None:
    plc, peer = plc_and_peer
    with plc.window(timeout_s=1.0) as inputs:
        assert inputs.window_open and inputs.line_running
        assert peer.received.busy and not peer.received.done
    assert peer.received.done and not peer.received.busy
    assert [(o.busy, o.done) for o in peer.history][-2:] == [(True, False), (False, True)]


def test_heartbeats_flow_both_ways(plc_and_peer: tuple[Plc, Any]) -> None:
    plc, peer = plc_and_peer
    plc.wait_window(timeout_s=1.0)
    first = peer.received.heartbeat
    plc.poll()
    assert peer.received.heartbeat == (first + 1) & 0xFFFF
    assert plc.heartbeat_alive()


def test_an_error_inside_the_window_signals_fault(plc_and_peer: tuple[Plc, Any]) -> None:
    plc, peer = plc_and_peer
    with pytest.raises(RuntimeError), plc.window(timeout_s=1.0):
        raise RuntimeError("measurement failed")
    assert peer.received.fault and not peer.received.busy and not peer.received.done


def test_lost_plc_heartbeat_means_not_ready(plc_and_peer: tuple[Plc, Any]) -> None:
    plc, peer = plc_and_peer
    peer.heartbeat_frozen = True
    with pytest.raises(DeviceTimeout, match="heartbeat lost"):
        plc.wait_window(timeout_s=0.3)


def test_line_stopped_never_opens_a_window(kind: str) -> None:
    stopped = ClampCycle(period_s=60.0, window_s=8.0, time_scale=0.002, line_running=False)
    with ExitStack() as stack:
        plc, _ = _open(kind, stopped, stack)
        with pytest.raises(DeviceTimeout, match="line not running"):
            plc.wait_window(timeout_s=0.2)


def test_modbus_plc_faults() -> None:
    from fakes.plc import PlcServer

    with (
        PlcServer(CYCLE) as server,
        open_plc(f"plc+modbus://127.0.0.1:{server.port}", **OPTS) as plc,
    ):
        server.fail_next("exception")
        with pytest.raises(DeviceFault):
            plc.poll()
        server.fail_next("drop", function_code=3)
        plc.poll()  # a read: reconnect and retry
        plc.wait_window(timeout_s=1.0)


@pytest.mark.parametrize("mode", ["mute", "garble"])
def test_modbus_plc_silent_or_garbled_peer(mode: str) -> None:
    from fakes.plc import PlcServer

    fast = OPTS | {"timeout_s": 0.2}
    with (
        PlcServer(CYCLE) as server,
        open_plc(f"plc+modbus://127.0.0.1:{server.port}", **fast) as plc,
    ):
        server.fail_next(mode, function_code=3)
        plc.poll()  # one bad exchange: reconnect and read again
        server.fail_next(mode, function_code=3)
        server.fail_next(mode, function_code=3)
        with pytest.raises(DeviceTimeout):  # still bad after the reconnect: typed, no hang
            plc.poll()
        plc.wait_window(timeout_s=1.0)  # the next poll reconnects
        assert server.received.heartbeat == plc.outputs.heartbeat


def test_modbus_plc_peer_gone_and_back() -> None:
    from fakes.plc import PlcServer

    with (
        PlcServer(CYCLE) as server,
        open_plc(f"plc+modbus://127.0.0.1:{server.port}", **OPTS) as plc,
    ):
        plc.poll()
        port = server.port
        server.close()
        with pytest.raises(DeviceConnectionError):
            plc.poll()
        with PlcServer(CYCLE, port=port):
            plc.wait_window(timeout_s=1.0)


def test_every_connect_resets_the_outputs(plc_and_peer: tuple[Plc, Any]) -> None:
    plc, peer = plc_and_peer
    plc.poll()
    plc.set_signals(busy=True, done=False, fault=True)
    assert peer.received.busy and peer.received.fault and peer.received.heartbeat > 0
    plc.close()
    plc.open()  # the handshake of the base class: outputs back to zero, heartbeat from 0
    assert peer.received == PlcOutputs()
    assert plc.outputs == PlcOutputs()
    assert not plc.heartbeat_alive()  # no PLC heartbeat seen on this connection yet


def test_a_withdrawn_window_is_seen_at_once(plc_and_peer: tuple[Plc, Any]) -> None:
    plc, _ = plc_and_peer
    opened = plc.wait_window(timeout_s=1.0)
    assert opened.window_open
    deadline = time.monotonic() + 1.0
    while plc.ready():  # the 16 ms window closes; ready() follows the PLC's status word
        assert time.monotonic() < deadline, "the window never closed"
    assert plc.heartbeat_alive()


def test_the_words_on_the_wire_follow_the_register_map() -> None:
    out = PlcOutputs(busy=True, done=False, fault=True, heartbeat=0x1_0005)
    assert encode_outputs(out) == (BUSY | FAULT, 5)
    assert decode_outputs(encode_outputs(out)) == PlcOutputs(True, False, True, 5)
    inputs = decode_inputs((WINDOW_OPEN | LINE_RUNNING, 77))
    assert inputs == PlcInputs(window_open=True, line_running=True, heartbeat=77)
    assert encode_inputs(inputs) == (WINDOW_OPEN | LINE_RUNNING, 77)


def test_the_cell_temperature_word_is_signed_centidegrees() -> None:
    for temp in (21.37, -5.25, 0.0, 327.67, -327.67):
        word = encode_temp(temp)
        assert 0 <= word <= 0xFFFF and decode_temp(word) == pytest.approx(temp, abs=0.005)
    assert encode_temp(None) == NO_TEMPERATURE and decode_temp(NO_TEMPERATURE) is None
    assert decode_temp(encode_temp(1e6)) == 327.67  # clamped, never the "no sensor" code
    assert decode_inputs((WINDOW_OPEN, 3, encode_temp(-1.5))).temp_c == -1.5
    assert decode_inputs((WINDOW_OPEN, 3)).temp_c is None  # a PLC without the word


def test_the_modbus_plc_reads_the_cell_temperature_from_its_peer() -> None:
    from fakes.plc import PlcServer

    with (
        PlcServer(CYCLE) as server,
        open_plc(f"plc+modbus://127.0.0.1:{server.port}", **OPTS) as plc,
    ):
        assert plc.poll().temp_c == 0.0  # a PLC program that never writes the word
        server.temperature = lambda: None
        deadline = time.monotonic() + 2.0
        while plc.poll().temp_c is not None:  # "no sensor": 0x8000
            assert time.monotonic() < deadline, "the no-sensor word never arrived"
        server.temperature = lambda: 24.56
        deadline = time.monotonic() + 2.0
        while plc.poll().temp_c != 24.56:  # the peer's next scan writes the word
            assert time.monotonic() < deadline, "the temperature word never arrived"
