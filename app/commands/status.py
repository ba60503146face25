"""`rvis status [--state-dir DIR] [--json]`: the state of the in-line service, from its control
socket; when no service is running, what its database and parameters say.

It imports only what it uses (the socket's client, SQLite, the state directory's layout): no
numerics, no devices, no service, and no cell file unless `--cell` names one (then the file is
read and checked whole). `rvis ctl` and `rvis state` share these helpers;
tests/app/test_light_commands.py holds all of them to it."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from app.commands import add_command
from app.errors import InputError, RvisError


def register(sub: Any) -> None:
    p = add_command(sub, "status")
    p.add_argument("--cell", help="cell configuration TOML (for [service] state_dir)")
    p.add_argument("--state-dir", help="state directory (default: [service] state_dir)")
    p.add_argument("--json", action="store_true", help="print the status as JSON")
    p.set_defaults(func=run)


def state_dir_of(args: argparse.Namespace) -> Path:
    """`--state-dir`, else the cell file's [service] state_dir (the file read and checked
    whole), else the default (app.state_defaults.DEFAULT_ROOT, no cell file loaded)."""
    if args.state_dir:
        return Path(args.state_dir)
    if args.cell is None:
        from app.state_defaults import DEFAULT_ROOT

        return Path(DEFAULT_ROOT)
    from app.config import load_cell

    return Path(load_cell(args.cell).service.state_dir)


def offline_status(state_dir: Path) -> dict[str, Any]:
    """What the files say when the service is not running (read-only)."""
    from app.line.maintenance_state import RECORDS_IN_STATUS, maintenance_json
    from app.line.statedir import StateDir, holder_pid
    from app.line.states import suspect_json
    from app.line.store import Store

    state = StateDir(state_dir)
    pid = holder_pid(state)
    if pid is not None:  # the lock is held, the socket not up yet: a service starting, or
        return _held(state, pid)  # `rvis maintain` (its record running)
    if not state.db.is_file():
        raise InputError("no service state here (no rvis.db)", file=state_dir)
    store = Store.read_only(state.db)
    try:
        active = store.active_alarms()
        alarms = [{k: a[k] for k in ("id", "code", "priority", "message", "state")} for a in active]
        pending = [c["id"] for c in store.calibrations("pending")]
        out = {
            "state": "not running",
            "params_version": state.current_version(),
            "pending_calibration": pending[-1] if pending else None,
            "measurements": store.counts(),
            "schedule": {"position": store.schedule_position()[0]},
            "alarms": alarms,
            "accuracy": _last_accuracy(store),
            "suspect_intervals": [suspect_json(r) for r in store.suspects(last=5)],
            "maintenance": maintenance_json(
                active, store.maintenance(last=RECORDS_IN_STATUS), state.root
            ),
        }
    finally:
        store.close()
    return out


def _last_accuracy(store: Any) -> dict[str, Any] | None:
    """The last U95 the service stated (its saved state's statement, as the running service's
    reply gives it; a state saved by an older rvis: the U95 its last window stored) with the
    window it was stated for (`window_utc`, null when not known); None before any."""
    from app.line.states import utc_text

    stated = store.last_statement()
    acc = (store.load_state() or {}).get("accuracy")
    if acc is None and stated is None:
        return None
    if acc is None:
        acc = {"u95_mm": stated["u95_mm"], "n": None, "basis": None, "limit_mm": None}
    same = stated is not None and stated["u95_mm"] == acc["u95_mm"]
    return {**acc, "window_utc": utc_text(float(stated["t"])) if same else None}


def _held(state: Any, pid: int) -> dict[str, Any]:
    """The state directory held, no control socket: a service starting, or `rvis maintain`
    running (a maintenance record `running`: state `maintenance`, with the procedure's
    progress)."""
    from app.line.maintenance_state import RECORDS_IN_STATUS, maintenance_json
    from app.line.store import Store

    starting = {"state": "starting", "pid": pid, "socket": False}
    if not state.db.is_file():
        return starting
    try:
        store = Store.read_only(state.db)
        try:
            m = maintenance_json(
                store.active_alarms(), store.maintenance(last=RECORDS_IN_STATUS), state.root
            )
        finally:
            store.close()
    except RvisError:  # being written or migrated this instant: say what the lock says
        return starting
    return (
        starting if m["running"] is None else {**starting, "state": "maintenance", "maintenance": m}
    )


def fetch_status(state_dir: Path) -> dict[str, Any]:
    from app.line.control import ControlClient
    from app.line.statedir import StateDir

    if Path(state_dir).exists() and not Path(state_dir).is_dir():
        raise InputError("not a state directory (a file)", file=state_dir)
    try:
        with ControlClient(StateDir(state_dir).socket, timeout_s=10.0) as client:
            reply = client.request("status")
    except (FileNotFoundError, ConnectionRefusedError):
        return offline_status(state_dir)
    except OSError as exc:  # the service went away meanwhile, or did not answer in time
        raise RvisError(f"{state_dir}: no answer from the service ({exc.strerror or exc})") from exc
    reply.pop("id", None)
    reply.pop("ok", None)
    return reply


def run(args: argparse.Namespace) -> int:
    status = fetch_status(state_dir_of(args))
    if args.json:
        print(json.dumps(status, indent=2))
        return 0
    print("\n".join(status_lines(status)))
    return 0


def status_lines(status: dict[str, Any]) -> list[str]:
    """The status in words, one fact a line (what `--json` has, compactly)."""
    from app.line.maintenance_state import maintenance_lines

    if status.get("state") == "maintenance":  # `rvis maintain` holds the state directory
        return [
            f"state               maintenance: `rvis maintain` (pid {status.get('pid')}) holds"
            " the state directory; `rvis run` once it has handed the cell back",
            *maintenance_lines(status.get("maintenance")),
        ]
    if status.get("socket") is False:  # the lock held, the control socket not up yet
        return [
            f"state               starting (pid {status.get('pid')}): the service holds the"
            " state directory and is getting ready; ask again in a moment"
        ]
    m = status.get("measurements", {})
    paused = status.get("paused") and status["state"] != "paused"  # a pause still to come
    state = f"{status['state']}" + (" (paused)" if paused else "")
    if status.get("step"):
        state += f": {status['step']}"
    lines = [
        f"state               {state}",
        f"parameters version  {status.get('params_version')}",
        f"pending calibration {status.get('pending_calibration') or '-'}",
    ]
    if "mode" in status:  # the running service's
        from app.line.states import hold_text

        lines.append(f"applies             {hold_text(status.get('auto_hold'), status['mode'])}")
    if "cell_temp_c" in status:
        temp = status["cell_temp_c"]
        lines.append(f"cell temperature    {'unknown' if temp is None else f'{temp:.1f} degC'}")
    lines += maintenance_lines(status.get("maintenance"))
    lines += _device_lines(status.get("devices"))
    from app.line.states import accuracy_text

    lines.append(f"accuracy            {accuracy_text(status)}")
    if "spheres" in status:  # the running service's
        lines.append(f"step                {_jump_text(status.get('jump'))}")
        lines += _sphere_lines(status["spheres"])
    lines.append(f"measurements        {m.get('ok', 0)} ok, {m.get('rejected', 0)} rejected")
    counters = status.get("counters")
    if counters:
        lines.append(
            f"windows             {counters['windows']} ({counters['overruns']} overruns, "
            f"{counters['withdrawn']} withdrawn)"
        )
    alarms = status.get("alarms", [])
    lines.append(f"alarms              {len(alarms) or 'none'}")
    lines += [f"  #{a['id']} {a['priority']:<7} {a['state']:<8} {a['message']}" for a in alarms]
    opcua = status.get("opcua")
    if opcua is not None:  # the running service's OPC UA server
        lost = opcua.get("events_dropped", 0)
        lines.append(
            f"OPC UA              {lost or 'no'} alarm or body events lost on the way to the server"
        )
    lines += _suspect_lines(status)
    return lines


def _device_lines(devices: dict[str, Any] | None) -> list[str]:
    """`devices  robot ok, plc no heartbeat, ...`, then the last error of each that has one."""
    if not devices:
        return []
    out = ["devices             " + ", ".join(f"{k} {d['state']}" for k, d in devices.items())]
    out += [
        f"  {k}: last error {d['last_error']} ({d.get('last_error_utc') or 'time unknown'})"
        for k, d in devices.items()
        if d.get("last_error")
    ]
    return out


def _jump_text(ep: dict[str, Any] | None) -> str:
    """The one estimator's jump in hand (app.line.jumps), in words."""
    if not ep:
        return "none found (the one estimator watches every measurement)"
    what = ep.get("what") or "finding what moved"
    if ep.get("closed"):
        return f"{ep.get('text', '')}: {what}; corrected, its group watched"
    done = ep.get("corrected_version")
    state = f"corrected by version {done}, confirming" if done else "correcting"
    return f"{ep.get('text', '')}: {what}; {state}"


def _sphere_lines(spheres: dict[str, Any]) -> list[str]:
    """`spheres  residual of the newest measurement, mm: P1 0.041, P2 - ...` (the estimator's
    window: app.line.estimate)."""
    if not spheres:
        return []

    def mm(v: Any) -> str:
        return f"{v:.3f}" if isinstance(v, int | float) else "-"

    newest = ", ".join(f"{k} {mm(v.get('residual_mm'))}" for k, v in sorted(spheres.items()))
    left = ", ".join(f"{k} {mm(v.get('posterior_rms_mm'))}" for k, v in sorted(spheres.items()))
    return [
        f"spheres             residual of the newest measurement, mm: {newest}",
        f"                    RMS left by the estimator, mm: {left}",
    ]


def _suspect_lines(status: dict[str, Any]) -> list[str]:
    """The last suspect intervals (`rvis state suspects` lists all)."""
    from app.line.states import bodies_text

    out = []
    intervals = status.get("suspect_intervals") or []
    out.append(f"suspect intervals   {len(intervals) or 'none'} (the last {len(intervals)})")
    for r in intervals:
        size = "-" if r.get("size_mm") is None else f"{r['size_mm']:.3f} mm"
        bodies = r.get("bodies") or []
        out.append(
            f"  #{r['id']} {r.get('start_utc')} .. {r.get('end_utc') or 'OPEN'}  {size}"
            f"  {r.get('group') or ''}" + (f"  bodies {bodies_text(bodies)}" if bodies else "")
        )
    return out
