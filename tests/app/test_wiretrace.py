"""`[devices] trace = true` on the simulated line, and `rvis devices trace FILE`: a window's
traffic of every device in the state directory's rotating trace, printed readably."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from app.commands.cli import main
from app.formats.wiretrace import TraceRecord, format_records
from app.line.statedir import StateDir


def test_a_simulated_run_traces_every_device_and_the_trace_prints(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cell = tmp_path / "cell.toml"
    # no body phase: its bit's edges are changes too, and this counts the polls between them
    cell.write_text("[devices]\ntrace = true\n[simline]\nbody_s = 0\n")
    state = tmp_path / "state"
    argv = ["run", "--sim", "--geometric", "--windows", "1", "--json"]
    assert main([*argv, "--cell", str(cell), "--state-dir", str(state)]) == 0
    capsys.readouterr()
    path = StateDir(state).wire_trace
    lines = [json.loads(line) for line in path.read_text().splitlines()]
    assert lines[0]["format"] == "rvis-wire/1"
    devices = {r["dev"] for r in lines[1:]}
    assert devices == {"plc", "robot", "tracker"}  # geometric: no camera, no galvo
    moves = [r for r in lines if "FRC_JointMotionJRep" in r.get("msg", "")]
    assert [r["dir"] for r in moves][:2] == [">", "<"]  # a motion and its completion

    assert main(["devices", "trace", str(path), "--device", "robot"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out and all("  robot  " in line for line in out)
    reply = next(line for line in out if "FRC_JointMotionJRep" in line and " <  " in line)
    assert reply.endswith(" ms]")  # the round trip since the request

    assert main(["devices", "trace", str(path), "--json"]) == 0
    printed = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert len(printed) == len(lines) - 1 and all(r["wall"] > 1e9 for r in printed)

    # the PLC's polls that changed nothing fold (issue 30 item 10); --all prints every record
    plc = [r for r in lines[1:] if r["dev"] == "plc"]
    assert main(["devices", "trace", str(path), "--device", "plc", "--all"]) == 0
    assert len(capsys.readouterr().out.splitlines()) == len(plc)
    assert main(["devices", "trace", str(path), "--device", "plc"]) == 0
    out = capsys.readouterr().out.splitlines()
    folds = [
        line for line in out if line.endswith("lines of plc polls: nothing changed but counters)")
    ]
    assert folds and len(out) < len(plc) / 5
    folded = sum(int(line.split("(")[1].split()[0]) for line in folds)
    assert folded + len(out) - len(folds) == len(plc)  # every record printed or counted


def _records(*exchanges: tuple[str, str]) -> list[TraceRecord]:
    out = []
    for k, (request, reply) in enumerate(exchanges):
        out += [TraceRecord(2 * k, "plc", ">", request), TraceRecord(2 * k + 1, "plc", "<", reply)]
    return out


def test_a_poll_folds_when_only_counters_moved_and_a_change_prints() -> None:
    # the PLC's heartbeat (word 1) steps by 3 per poll (a fast simulated clock), the service's
    # (the write's last number) by 1; word 0 is the window bit: 2 (line running), 3 (open)
    def poll(k: int, bits: int = 2) -> tuple[str, str]:
        return ("read 0 count 3", f"fc3 0: [{bits}, {80 + 3 * k}, 2009]")

    def beat(k: int) -> tuple[str, str]:
        return (f"write 10: [0, {1500 + k}]", "fc16 10: ok")

    exchanges = [x for k in range(10) for x in (poll(k), beat(k))]
    exchanges += [poll(10, bits=3), beat(10), poll(11, bits=3), beat(11), poll(12)]
    out = [line[30:] for line in format_records(_records(*exchanges), fold=True)]  # no times
    shown = [line for line in out if "polls:" not in line]
    assert shown == [
        # the first exchange of each shape, and the counters' first two steps (learning)
        *("plc      >  read 0 count 3", "plc      <  fc3 0: [2, 80, 2009]  [1000.00 ms]"),
        *("plc      >  write 10: [0, 1500]", "plc      <  fc16 10: ok  [1000.00 ms]"),
        *("plc      >  read 0 count 3", "plc      <  fc3 0: [2, 83, 2009]  [1000.00 ms]"),
        *("plc      >  write 10: [0, 1501]", "plc      <  fc16 10: ok  [1000.00 ms]"),
        *("plc      >  read 0 count 3", "plc      <  fc3 0: [2, 86, 2009]  [1000.00 ms]"),
        *("plc      >  write 10: [0, 1502]", "plc      <  fc16 10: ok  [1000.00 ms]"),
        # the window opens and closes: changes, printed however the heartbeat moved
        *("plc      >  read 0 count 3", "plc      <  fc3 0: [3, 110, 2009]  [1000.00 ms]"),
        *("plc      >  read 0 count 3", "plc      <  fc3 0: [2, 116, 2009]  [1000.00 ms]"),
    ]
    assert "plc      .  (28 lines of plc polls: nothing changed but counters)" in out
    assert len(list(format_records(_records(*exchanges)))) == 2 * len(exchanges)  # --all


def test_rotated_files_print_oldest_first_and_bad_lines_are_named(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from drivers.trace import WireTrace

    path = tmp_path / "wire.jsonl"
    with WireTrace(path, max_bytes=1024, keep=5) as trace:
        channel = trace.channel("galvo")
        for n in range(40):
            channel.tx(f":SOUR:VOLT {n}")
    assert main(["devices", "trace", str(path), "--rotated", "--json"]) == 0
    msgs = [json.loads(line)["msg"] for line in capsys.readouterr().out.splitlines()]
    sent = [int(m.split()[-1]) for m in msgs if m.startswith(":SOUR")]
    assert sent == sorted(sent) and sent[-1] == 39  # in order across the files
    with path.open("a") as f:
        f.write('{"t": 1.0, "dev": "galvo", "msg": "no direction"}\n')
    n_lines = len(path.read_text().splitlines())
    assert main(["devices", "trace", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert f"{path}:{n_lines}: not a trace record" in err and len(err.splitlines()) == 1
    assert main(["devices", "trace", str(tmp_path / "none.jsonl")]) == 2
