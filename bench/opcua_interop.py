"""rvis's OPC UA server seen by a second, independent client implementation: node-opcua (the
Node.js SDK, npm `node-opcua-client`), on the simulated line (issue 21).

    npm install --prefix ~/.cache/rvis-node node-opcua-client@2.186.4
    nice -n 5 .venv/bin/python bench/opcua_interop.py --node-modules ~/.cache/rvis-node/node_modules

bench/opcua_interop.mjs finds the machine by the official OPC 40001-1 type NodeIds alone and
reads Identification and MachineryItemState through them (issue 29), resolves the variables by
browse path, reads them, subscribes to Windows and to AlarmConditionType events; this script
runs the service on the simulated line (x300, geometric) with the OPC UA server (allow_ack),
pauses it and compares what node-opcua read with the service's status reply, plays a controller
alarm, lets node-opcua acknowledge it (the audit row is checked, the comment comes back in the
event's Comment), resets, plays an alarm blip (raised and cleared in one transaction: two
events, issue 39) and prints one line per check. Exit status 1 if any failed.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import queue
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.threads import limit_blas_threads

limit_blas_threads()

from app.config import load_cell
from app.line.launch import hold_state, serving
from app.line.opcua.server import OpcUaServer
from app.sim.line_run import SimulatedLineRun
from bench.opcua import _free_port
from fakes.line_faults import Fault

HERE = Path(__file__).resolve().parent
CELL = '[simline]\nscale = 300.0\nwarmup_k = 0.0\n[opcua]\nmachine_name = "interop-cell"\n'


class Node:
    """bench/opcua_interop.mjs as a child process: JSON lines out, commands in."""

    def __init__(self, url: str, machine: str, node_modules: Path) -> None:
        env = {"NODE_OPCUA": str(node_modules / "node-opcua-client"), "PATH": "/usr/bin:/bin"}
        self.proc = subprocess.Popen(
            ["node", str(HERE / "opcua_interop.mjs"), url, machine],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env,
        )  # fmt: skip
        self.lines: queue.Queue[dict[str, Any]] = queue.Queue()
        self.seen: list[dict[str, Any]] = []  # every line, in order
        self._pos = 0  # after the line wait() last returned
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for raw in self.proc.stdout:
            if raw.startswith('{"k":'):  # node-opcua prints its own notes too
                self.lines.put(json.loads(raw))

    def send(self, line: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()

    def mark(self) -> int:
        """A point in the output to wait from (lines arrive in any order around a call)."""
        self._drain()
        return len(self.seen)

    def _drain(self) -> None:
        while True:
            try:
                self.seen.append(self.lines.get_nowait())
            except queue.Empty:
                return

    def wait(
        self, pred: Callable[[dict[str, Any]], bool], timeout_s: float = 20.0, since: int = -1
    ) -> dict:
        """The first line from `since` (default: after the last one returned) that satisfies
        pred."""
        self._drain()
        start = self._pos if since < 0 else since
        for i in range(start, len(self.seen)):
            if pred(self.seen[i]):
                self._pos = i + 1
                return self.seen[i]
        deadline = time.monotonic() + timeout_s
        while True:
            r = self.lines.get(timeout=max(0.01, deadline - time.monotonic()))
            self.seen.append(r)
            if pred(r):
                self._pos = len(self.seen)
                return r

    def close(self) -> None:
        if self.proc.poll() is None:
            self.send("quit")
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()


def compare(read: dict[str, Any], status: dict[str, Any]) -> list[str]:
    """Differences between node-opcua's reads and the status reply."""
    want = {
        "ServiceState": status["state"],
        "Step": status["step"],
        "CalibrationVersion": status["calibration"]["version"],
        "CalibrationRmsMm": status["calibration"]["rms_mm"],
        "PendingCalibration": status["pending_calibration"] or 0,
        "Windows": status["counters"]["windows"],
        "Overruns": status["counters"]["overruns"],
        "MeasurementsOk": status["measurements"]["ok"],
        "MeasurementsRejected": status["measurements"]["rejected"],
        "CellTemperatureC": status["cell_temp_c"],
        "ActiveAlarms": len(status["alarms"]),
        "MachineryItemState": "OutOfService",
    }
    out = []
    for name, value in want.items():
        got = read[name]
        expect_status = "BadNoValue" if value is None else "Good"
        if got["status"] != expect_status or (value is not None and got["value"] != value):
            out.append(f"{name}: node-opcua {got}, rvis status {value!r}")
    return out


def run(node_modules: Path) -> list[tuple[str, bool, str]]:
    checks: list[tuple[str, bool, str]] = []
    with tempfile.TemporaryDirectory() as tmp:
        cell = Path(tmp) / "cell.toml"
        cell.write_text(CELL, encoding="utf-8")
        cfg = load_cell(cell)
        url = f"opc.tcp://127.0.0.1:{_free_port()}/rvis"
        state = Path(tmp) / "state"
        with (
            hold_state(state),
            SimulatedLineRun(cfg, state, seed=4, geometric=True) as line,
            serving(line.service),
        ):
            svc = line.service
            settings = dataclasses.replace(
                svc.settings.opcua, enabled=True, endpoint=url, allow_ack=True
            )
            with OpcUaServer(svc, settings):
                line.start_service()
                node = Node(url, "interop-cell", node_modules)
                try:
                    checks += scenario(line, node)
                finally:
                    node.close()
    return checks


def scenario(line: SimulatedLineRun, node: Node) -> list[tuple[str, bool, str]]:
    svc = line.service
    checks = []
    resolved = node.wait(lambda r: r["k"] == "resolved")
    checks.append(("browse paths resolved by namespace URI", True, f"{resolved['n']} nodes"))
    official = node.wait(lambda r: r["k"] == "official")
    machines = official["machines"]
    found = machines[0] if len(machines) == 1 else {}
    ident = found.get("identification", {})
    checks.append(
        (
            "machine found by the official type NodeIds",
            bool(found) and found["browseName"].endswith("interop-cell"),
            f"{found.get('browseName')}: HasAddIn {found.get('identificationType')}"
            f" (MachineIdentificationType), {found.get('stateType')}"
            " (MachineryItemState_StateMachineType)",
        )
    )
    checks.append(
        (
            "Identification through MachineIdentificationType",
            ident.get("Manufacturer") == "rvis" and bool(ident.get("SerialNumber")),
            ", ".join(f"{k} {v}" for k, v in sorted(ident.items())),
        )
    )
    checks.append(
        (
            "MachineryItemState through its type",
            found.get("currentState") == found.get("stateNode", "").split(":")[-1],
            f"CurrentState {found.get('currentState')}, Id {found.get('stateId')}"
            f" -> {found.get('stateNode')}",
        )
    )
    versions = official["namespaceVersions"]
    checks.append(
        (
            "Server/Namespaces: DI and Machinery versions",
            versions.get("http://opcfoundation.org/UA/DI/") == "1.04.0"
            and versions.get("http://opcfoundation.org/UA/Machinery/") == "1.03.0",
            ", ".join(f"{k} {v}" for k, v in versions.items()),
        )
    )
    node.wait(lambda r: r["k"] == "ready")
    seen = [node.wait(lambda r: r["k"] == "data")["v"] for _ in range(3)]
    checks.append(("Windows data changes", seen == sorted(seen) and len(set(seen)) == 3, f"{seen}"))
    svc.request("pause").result(30)
    diffs: list[str] = ["not compared"]
    for _ in range(10):  # a calibration may land while paused
        node.send("read")
        read = node.wait(lambda r: r["k"] == "read")["values"]
        diffs = compare(read, svc.status())
        if not diffs:
            break
    checks.append(("read values equal the status reply", not diffs, "; ".join(diffs) or "12 of 12"))
    serial, revision = read["SerialNumber"]["value"], read["SoftwareRevision"]["value"]
    ident = f"SerialNumber {serial}, SoftwareRevision {revision}"
    checks.append(("Identification read", read["SerialNumber"]["status"] == "Good", ident))
    svc.request("resume").result(30)
    t0 = time.monotonic()
    line.line.inject(Fault.CONTROLLER_ALARM)
    raised = node.wait(
        lambda r: r["k"] == "event" and r["ConditionName"] == "device_fault" and r["ActiveState.Id"]
    )
    checks.append(
        (
            "device fault -> AlarmConditionType event",
            raised["Severity"] == 900 and raised["Retain"] is True,
            f"severity {raised['Severity']}, ConditionId {raised['ConditionId']},"
            f" {time.monotonic() - t0:.2f} s after the fault was armed",
        )
    )
    before = node.mark()
    node.send("ack device_fault")
    ack = node.wait(lambda r: r["k"] == "ack", since=before)
    if ack["status"] != "Good":
        return [*checks, ("Acknowledge method from node-opcua", False, str(ack))]
    acked = node.wait(
        lambda r: r["k"] == "event" and r["ConditionName"] == "device_fault" and r["AckedState.Id"],
        since=before,
    )
    audit = svc.store.actions()[-1]
    checks.append(
        (
            "Acknowledge method from node-opcua",
            ack["status"] == "Good"
            and acked["ActiveState.Id"]
            and audit["cmd"] == "ack"
            and audit["args"].get("via") == "opcua"
            and acked["Comment"] == audit["args"].get("comment"),
            f"{ack['status']}; audit {audit['cmd']} {audit['args']}; Comment {acked['Comment']!r}",
        )
    )
    svc.request("reset").result(30)
    cleared = node.wait(
        lambda r: (
            r["k"] == "event" and r["ConditionName"] == "device_fault" and not r["ActiveState.Id"]
        )
    )
    checks.append(("reset -> inactive event, Retain false", cleared["Retain"] is False, ""))
    return [*checks, blip(svc, node)]


def blip(svc: Any, node: Node) -> tuple[str, bool, str]:
    """An alarm raised and cleared in one transaction (no status reply between them): two
    events, raised then cleared (issue 39 item 2)."""
    code = "params_rebuilt"  # raised only at a start: the running line leaves it alone
    before = node.mark()
    t0 = time.monotonic()
    with svc.store.batch():
        svc.alarm(code, "a blip", "medium")
        svc.clear_alarms(code)
    blip_ms = 1000.0 * (time.monotonic() - t0)
    first = node.wait(lambda r: r["k"] == "event" and r["ConditionName"] == code, since=before)
    second = node.wait(lambda r: r["k"] == "event" and r["ConditionName"] == code)
    states = [first["ActiveState.Id"], second["ActiveState.Id"]]
    return (
        f"alarm blip of {blip_ms:.0f} ms -> raise and clear events",
        states == [True, False],
        f"ActiveState.Id {states}, Time {first['Time']} / {second['Time']}",
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--node-modules", type=Path, required=True, help="where node-opcua-client is")
    args = p.parse_args(argv)
    if shutil.which("node") is None or not (args.node_modules / "node-opcua-client").is_dir():
        print("needs node and node-opcua-client (see --help)", file=sys.stderr)
        return 2
    checks = run(args.node_modules)
    width = max(len(c[0]) for c in checks)
    for name, ok, detail in checks:
        print(f"{'ok  ' if ok else 'FAIL'} {name:<{width}}  {detail}")
    return 0 if all(ok for _, ok, _ in checks) else 1


if __name__ == "__main__":
    sys.exit(main())
