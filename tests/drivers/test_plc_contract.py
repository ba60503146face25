"""PLC contract: one test body per behaviour, run on fake://, the pymodbus PLC peer and a real
PLC (``RVIS_PLC_URL``). A real PLC is opened read-only: the handshake tests that write the app's
outputs run there only with ``RVIS_PLC_WRITE=1`` (tests/drivers/backends.py). What the PLC holds
is read back through the driver (``read_outputs``), the same on every back end."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import ExitStack
from dataclasses import dataclass
from typing import Any

import pytest

from drivers import DeviceConfigError, DeviceConnectionError, DeviceFault, DeviceTimeout, open_plc
from drivers.plc import (
    BUSY,
    FAULT,
    LINE_RUNNING,
    NO_TEMPERATURE,
    WINDOW_OPEN,
    Plc,
    PlcInputs,
    PlcOutputs,
    decode_body_id,
    decode_inputs,
    decode_outputs,
    decode_temp,
    encode_body_id,
    encode_inputs,
    encode_outputs,
    encode_temp,
)
from fakes.devices import ClampCycle, FakePlc
from tests.drivers.backends import (
    HARDWARE,
    backends,
    fake_only,
    plc_window_s,
    plc_writes_allowed,
    real_url,
)

# 60 s cycle with an 8 s window, compressed 500x: 120 ms period, 16 ms window, 1 ms beat
CYCLE = ClampCycle(period_s=60.0, window_s=8.0, beat_s=0.5, time_scale=0.002)
OPTS: dict[str, Any] = {"poll_s": 0.001, "heartbeat_timeout_s": 0.05, "timeout_s": 0.5}
REAL_OPTS: dict[str, Any] = {"poll_s": 0.05, "heartbeat_timeout_s": 3.0, "timeout_s": 2.0}


def _open(kind: str, cycle: ClampCycle, stack: ExitStack) -> tuple[Plc, Any]:
    if kind == "fake":
        plc = stack.enter_context(open_plc("fake://", cycle=cycle, **OPTS))
        assert isinstance(plc, FakePlc)
        return plc, plc
    from fakes.plc import PlcServer

    server = stack.enter_context(PlcServer(cycle))
    return stack.enter_context(open_plc(f"plc+modbus://127.0.0.1:{server.port}", **OPTS)), server


@dataclass
class PlcRig:
    plc: Plc
    peer: Any  # the fake PLC or the peer server; None on a real PLC
    window_s: float  # how long a handshake test waits for a clamp window

    def writable(self) -> Plc:
        """The PLC for a test that writes outputs (skipped on a read-only real PLC)."""
        if self.plc.read_only:
            pytest.skip("a real PLC's outputs are written only with RVIS_PLC_WRITE=1")
        return self.plc


@pytest.fixture(params=backends("plc", ["fake", "modbus"]))
def kind(request: pytest.FixtureRequest) -> str:
    return str(request.param)


@pytest.fixture
def rig(kind: str) -> Iterator[PlcRig]:
    with ExitStack() as stack:
        if kind == HARDWARE:
            url = real_url("plc")
            options = REAL_OPTS | {"read_only": not plc_writes_allowed()}
            plc = stack.enter_context(open_plc(url, **options))
            yield PlcRig(plc, None, plc_window_s())
        else:
            plc, peer = _open(kind, CYCLE, stack)
            yield PlcRig(plc, peer, 1.0)


def _wait_heartbeat_change(plc: Plc) -> int:
    """Poll until the PLC's heartbeat changes (within the heartbeat timeout); the new value."""
    first = plc.poll().heartbeat
    deadline = time.monotonic() + plc.heartbeat_timeout_s
    while (beat := plc.poll().heartbeat) == first:
        assert time.monotonic() < deadline, "the PLC heartbeat did not change"
        time.sleep(plc.poll_s)  # sleep-ok: the heartbeat is read over Modbus, polled
    return beat


def test_reads_the_inputs_and_sees_the_heartbeat(rig: PlcRig) -> None:
    plc = rig.plc
    _wait_heartbeat_change(plc)
    assert plc.heartbeat_alive()
    inputs = plc.poll()
    assert 0 <= inputs.heartbeat <= 0xFFFF
    assert plc.describe()
    if rig.peer is None:  # a real PLC: its own values, within what the words can say
        assert inputs.temp_c is None or -40.0 <= inputs.temp_c <= 100.0
        return
    # the simulated PLC's values are known: its line runs; fake:// sends no temperature word,
    # the peer's PLC program never writes it (0x0000: 0 degC); the heartbeat is the cycle's
    # beat count since the PLC started (read between two bounds of the elapsed time)
    assert inputs.line_running
    assert inputs.temp_c == (None if isinstance(rig.peer, FakePlc) else 0.0)
    lo = _beats(rig.peer)
    beat = plc.poll().heartbeat
    hi = _beats(rig.peer)
    # (the peer's register scan may lag a beat; the 16-bit word wraps)
    assert (beat - (lo - 2)) % 0x10000 <= hi - lo + 2, (lo, beat, hi)


def _beats(peer: Any) -> int:
    """The beats of the simulated PLC's cycle since it started (its heartbeat, not wrapped)."""
    fake = isinstance(peer, FakePlc)
    elapsed = peer._elapsed() if fake else peer.clock.monotonic() - peer.t0
    return int(elapsed / peer.cycle.time_scale / peer.cycle.beat_s)


def test_read_only_never_writes(rig: PlcRig) -> None:
    """A read-only connection to the same PLC polls, refuses to write, and leaves the app's
    words as they were (no reset, no heartbeat). fake:// is a PLC of its own: it holds the
    words a writing connection left (busy, heartbeat 41) before the read-only one opens."""
    rig.plc.poll()  # a heartbeat written: the words are not the reset's
    before = rig.plc.read_outputs()
    if rig.peer is not None:  # what a reset would write is told apart
        assert before != PlcOutputs()
    if rig.peer is None:
        ro = open_plc(real_url("plc"), read_only=True, **REAL_OPTS)
    elif isinstance(rig.peer, FakePlc):
        ro = FakePlc(CYCLE, read_only=True, **OPTS)
        before = ro.received = PlcOutputs(busy=True, done=False, fault=False, heartbeat=41)
    else:
        ro = open_plc(f"plc+modbus://127.0.0.1:{rig.peer.port}", read_only=True, **OPTS)
    with ro:
        held = ro.read_outputs()
        assert held == before
        ro.poll()
        ro.poll()
        with pytest.raises(DeviceConfigError, match="read-only"):
            ro.set_signals(busy=True, done=False, fault=False)
        assert ro.read_outputs() == held
    if not isinstance(rig.peer, FakePlc):
        assert rig.plc.read_outputs() == before


def test_waits_for_the_window_and_signals_busy_then_done(rig: PlcRig) -> None:
    plc = rig.writable()
    with plc.window(timeout_s=rig.window_s) as inputs:
        assert inputs.window_open and inputs.line_running
        held = plc.read_outputs()
        assert held.busy and not held.done and not held.fault
    held = plc.read_outputs()
    assert held.done and not held.busy and not held.fault
    if rig.peer is not None:
        assert [(o.busy, o.done) for o in rig.peer.history][-2:] == [(True, False), (False, True)]


def test_heartbeats_flow_both_ways(rig: PlcRig) -> None:
    plc = rig.writable()
    first = plc.read_outputs().heartbeat
    plc.poll()
    assert plc.read_outputs().heartbeat == (first + 1) & 0xFFFF == plc.outputs.heartbeat
    _wait_heartbeat_change(plc)
    assert plc.heartbeat_alive()


def test_an_error_inside_the_window_signals_fault(rig: PlcRig) -> None:
    plc = rig.writable()
    with pytest.raises(RuntimeError), plc.window(timeout_s=rig.window_s):
        raise RuntimeError("measurement failed")
    held = plc.read_outputs()
    assert held.fault and not held.busy and not held.done


def test_every_connect_resets_the_outputs(rig: PlcRig) -> None:
    plc = rig.writable()
    plc.poll()
    plc.set_signals(busy=True, done=False, fault=True)
    held = plc.read_outputs()
    assert held.busy and held.fault and held.heartbeat > 0
    plc.close()
    plc.open()  # the handshake of the base class: outputs back to zero, heartbeat from 0
    assert plc.read_outputs() == PlcOutputs() == plc.outputs
    assert not plc.heartbeat_alive()  # no PLC heartbeat seen on this connection yet


def test_lost_plc_heartbeat_means_not_ready(rig: PlcRig) -> None:
    peer = fake_only(rig.peer, "heartbeat freeze")
    peer.heartbeat_frozen = True
    with pytest.raises(DeviceTimeout, match="heartbeat lost"):
        rig.plc.wait_window(timeout_s=0.3)


@pytest.mark.parametrize("kind", ["fake", "modbus"])
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


def test_a_withdrawn_window_is_seen_at_once(rig: PlcRig) -> None:
    plc = rig.plc
    opened = plc.wait_window(timeout_s=rig.window_s)
    assert opened.window_open
    deadline = time.monotonic() + rig.window_s
    while plc.ready():  # the window closes; ready() follows the PLC's status word
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


def test_the_body_id_words_hold_a_32_bit_number_or_an_8_character_serial() -> None:
    for number in (1, 100001, 0x12345678, 0xFFFFFFFF):
        words = encode_body_id(number, "u32")
        assert len(words) == 2 and all(0 <= w <= 0xFFFF for w in words)
        assert decode_body_id(words, "u32") == number
    assert encode_body_id(0x0001_86A1, "u32") == (0x0001, 0x86A1)  # high word first
    assert decode_body_id((0, 0), "u32") is None  # 0: no body clamped
    for serial in ("B0100001", "WVW1234", "A"):
        words = encode_body_id(serial, "serial8")
        assert len(words) == 4 and decode_body_id(words, "serial8") == serial
    assert encode_body_id("AB", "serial8") == (0x4142, 0, 0, 0)  # the first in the high byte
    assert decode_body_id((0x4142, 0x2020, 0x2020, 0x2020), "serial8") == "AB"  # space-padded
    assert decode_body_id((0, 0, 0, 0), "serial8") is None  # blank: no body
    assert decode_body_id((0x2020,) * 4, "serial8") is None
    with pytest.raises(DeviceConfigError, match="body id format"):
        decode_body_id((1, 2), "u64")


@pytest.mark.parametrize("kind", ["fake", "modbus"])
def test_the_simulated_plc_holds_the_number_of_the_body_it_clamps(kind: str) -> None:
    """Period k of the clamp cycle holds body first_body + k (the fake counts bodies); read in
    one request, in the format the PLC writes it; a PLC program that never writes the words
    reads as no body."""
    cycle = ClampCycle(period_s=600.0, window_s=8.0, beat_s=0.5, first_body=555)
    assert [cycle.body(t) for t in (0.0, 599.0, 600.0, 1250.0)] == [555, 555, 556, 557]
    assert cycle.window_body(3) == 558
    for fmt, expected in (("u32", 555), ("serial8", "B0000555"), (None, None)):
        with ExitStack() as stack:
            if kind == "fake":
                plc = stack.enter_context(open_plc("fake://", cycle=cycle, **OPTS))
                assert isinstance(plc, FakePlc)
                plc.body_format = fmt
            else:
                from fakes.plc import PlcServer

                server = PlcServer(cycle)
                server.body_format = fmt
                stack.enter_context(server)
                plc = stack.enter_context(open_plc(f"plc+modbus://127.0.0.1:{server.port}", **OPTS))
            assert plc.read_body_id(fmt or "u32") == expected
