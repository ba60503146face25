"""`[devices] trace = true` on the simulated line, and `rvis devices trace FILE`: a window's
traffic of every device in the state directory's rotating trace, printed readably."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from app.commands.cli import main
from app.line.statedir import StateDir


def test_a_simulated_run_traces_every_device_and_the_trace_prints(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cell = tmp_path / "cell.toml"
    cell.write_text("[devices]\ntrace = true\n")
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
