"""`rvis run [--cell cell.toml] [--state-dir DIR] [--plan plan.json]`: the unattended in-line
service (DESIGN.md section 6) on the devices of the cell file. Logs are JSON lines on stdout;
operators use `rvis status`, `rvis ctl` and `rvis tui` (the control socket in the state
directory).

Without --cell and --plan, a state directory named by --state-dir supplies them
(`STATE_DIR/cell.toml`, `STATE_DIR/plan.json`: what `rvis commission` leaves there), as it
supplies the sensor calibration (`STATE_DIR/sensor.toml`) when --sensor is not given.

`rvis run --sim [--geometric] [--seed N] [--windows N] [--json] [--no-bodies]`: the same
service on the simulated line (app/sim/line_run.py): every device peer on loopback, reached
through the real drivers, one simulated cell drifting with time ([simline] of the cell file:
clamp cycle, warm-up, knock, the pace), measuring its bodies by the simulated part type's
feature plan (put in a state directory that has none; `--no-bodies`: spheres only). Its time
is virtual (passed by what is simulated: a seed gives one run). With --windows it runs as fast
as the CPU, stops after N windows and prints a summary (windows, measurements, overruns,
calibrations applied and rejected, alarms, true RMSE at the validation positions); without,
paced at [simline] scale for a person who watches, it runs until SIGTERM or Ctrl-C.

`fake://` devices in the cell file are refused with one line pointing to `rvis devices sim`
(the simulated line's devices as their own process, with a cell file naming them).

A device that cannot be reached at start (its URL right, nothing answering) does not end the
command: the service starts in FAULT with a `device_unreachable` alarm naming it, answers
`rvis status`, and retries with back-off (app/line/startup.py); a wrong cell file or URL is
still exit 2 at once.

stdout carries JSON lines only, in every mode (docs/operations.md, "What the service prints"):
the service's log (without --windows), the simulation's `sim_window` line after every window
(its truth: the true RMSE of the parameters in force) and, with --windows, a last
`sim_summary` line; `--json` prints the summary alone as one JSON document. The words for a
person (the start line, the batch summary) go to stderr."""

from __future__ import annotations

import argparse
import contextlib
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from app.commands import add_command
from app.commands.args import int_at_least, say_waiting, sim_seed
from app.errors import InputError


def register(sub: Any) -> None:
    p = add_command(sub, "run")
    p.add_argument(
        "--cell",
        help="cell configuration TOML (default: STATE_DIR/cell.toml when --state-dir names a"
        " directory that has one, as `rvis commission` leaves it; else the embedded cell)",
    )
    p.add_argument("--state-dir", help="state directory (default: [service] state_dir)")
    p.add_argument(
        "--plan",
        help="plan JSON from `rvis plan` (default: STATE_DIR/plan.json; --sim without one:"
        " the simulated line plans its own)",
    )
    p.add_argument("--params", help="starting parameters JSON when the state has none yet")
    p.add_argument(
        "--sensor",
        help="sensor calibration TOML from `rvis sensor calibrate` (default: STATE_DIR/sensor.toml"
        " if any, else the design)",
    )
    p.add_argument("--sim", action="store_true", help="run on the simulated line (no hardware)")
    p.add_argument("--geometric", action="store_true", help="--sim: skip rendering (long runs)")
    p.add_argument("--seed", type=int_at_least(0), help="--sim: seed (default [simulation])")
    p.add_argument("--windows", type=int_at_least(1), help="--sim: stop after N windows")
    p.add_argument("--json", action="store_true", help="--sim --windows: summary as JSON")
    p.add_argument(
        "--no-bodies",
        action="store_true",
        help="--sim: spheres only (no feature plan put in the state directory, no body measured)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from app.config.check import in_cell_file

    try:
        return _run(args)
    except InputError as exc:  # a setting found wrong once used (a group): where it is set
        raise in_cell_file(exc, _cell_path(args)) from None


def _run(args: argparse.Namespace) -> int:
    if args.sim:
        return run_sim(args)
    if args.geometric or args.windows or args.seed is not None or args.no_bodies:
        raise InputError("--geometric, --seed, --windows and --no-bodies need --sim")
    from app.formats.params import carried_from_json
    from app.line.launch import hold_state
    from app.line.settings import from_cell
    from app.line.statedir import StateDir
    from app.line.station import Station, cell_guard
    from drivers.errors import DeviceConfigError

    cfg = _cell(args)
    settings = from_cell(cfg, args.state_dir)
    plan = Path(args.plan) if args.plan else StateDir(settings.state_dir).plan
    if not plan.is_file():
        raise InputError(
            "no plan file: commission the cell into this state directory (`rvis commission"
            " --state-dir DIR`), or give a plan from `rvis plan --out FILE` with --plan",
            file=plan,
        )
    _refuse_fakes(cfg)
    # a rigid file carried into a compliant [service] model at its calibration temperature
    x0 = carried_from_json(cfg.service_model(), args.params)[1] if args.params else None
    sensor_model = _sensor_model(args, settings.state_dir)
    with hold_state(settings.state_dir, settings.ops.operators_group) as state:
        try:
            trace = cfg.devices.wire_trace(state.wire_trace)
            station = Station.open(
                cfg.devices.urls(),
                guard=cell_guard(cfg),
                options={"camera": {"settings": cfg.camera.settings()}},
                trace=trace,
                defer_unreachable=True,  # the service starts in FAULT and retries it
            )
        except DeviceConfigError as exc:
            raise InputError(str(exc), file=cfg.source, field="devices") from exc
        for family, error in station.unreachable.items():
            print(
                f"rvis run: {family} unreachable ({type(error).__name__}: {error}): starting in"
                " FAULT, retrying (`rvis status`)",
                file=sys.stderr,
                flush=True,
            )
        return _serve_station(station, cfg, settings, plan, x0, sensor_model)


def _cell(args: argparse.Namespace) -> Any:
    """--cell, else STATE_DIR/cell.toml when --state-dir names a directory that has one (the
    cell file `rvis commission` wrote there), else the embedded cell."""
    from app.config import load_cell

    return load_cell(_cell_path(args))


def _cell_path(args: argparse.Namespace) -> Path | None:
    """The cell file `_cell` reads (None: the embedded cell)."""
    from app.line.statedir import StateDir

    if args.cell is None and args.state_dir:
        commissioned = _existing(StateDir(args.state_dir).cell)
        if commissioned is not None:
            return commissioned
    return None if args.cell is None else Path(args.cell)


def _refuse_fakes(cfg: Any) -> None:
    """`fake://` devices live inside one process with their simulated cell (`rvis run --sim`):
    the service of a cell file reaches the simulated line's devices over their protocols, as
    `rvis devices sim` serves them."""
    fakes = [f for f, url in cfg.devices.urls().items() if url.startswith("fake://")]
    if fakes:
        raise InputError(
            f"fake:// ({', '.join(fakes)}) runs only inside `rvis run --sim`: start the simulated"
            " line's devices with `rvis devices sim` and run on the cell file it writes",
            file=cfg.source,
            field=f"devices.{fakes[0]}",
        )


def _existing(path: Path) -> Path | None:
    """`path` when it is a file; None when it is not, or cannot be looked at (a state directory
    the user may not enter is refused, with its reason, when the state is taken)."""
    try:
        return path if path.is_file() else None
    except OSError:
        return None


def _sensor_model(args: argparse.Namespace, state_dir: Path) -> Any:
    """The sensor calibration to measure with: --sensor, else STATE_DIR/sensor.toml (what
    commissioning wrote), else None (the caller's default)."""
    from app.line.statedir import StateDir
    from vision.sensor_model import load_sensor_model

    state_sensor = StateDir(state_dir).sensor
    path = args.sensor or (state_sensor if state_sensor.is_file() else None)
    return load_sensor_model(path) if path else None


def _serve_station(
    station: Any, cfg: Any, settings: Any, plan: Path, x0: Any, sensor_model: Any
) -> int:
    from app.line.body_cycle import sweep_bodies
    from app.line.launch import build_service, json_logs, serve
    from app.line.measure import SweepSensor
    from vision.sensor_model import default_sensor_model

    with station:
        if station.camera is None or station.galvo is None:
            raise InputError("the service needs a camera and a galvo", field="devices")
        model = sensor_model or default_sensor_model()
        sensor = SweepSensor(
            station.camera,
            station.galvo,
            model,
            settings.sweep,
            keep_frames=settings.ops.raw_sweeps_keep > 0,
        )
        # the part type's features when the state directory has a plan (features.toml)
        bodies = sweep_bodies(
            settings.state_dir, cfg.T_part_base, station.camera, station.galvo, model
        )
        service = build_service(cfg, station, sensor, settings, plan, x0, bodies=bodies)
        json_logs()
        return _exit(serve(service))


def _exit(code: int) -> int:
    """The service's exit status, with one line on stderr when it ended on an error."""
    if code:
        import sys

        print(
            "rvis run: error: internal error (logged with its traceback): the cell is in FAULT;"
            " the supervisor restarts the service",
            file=sys.stderr,
        )
    return code


def run_sim(args: argparse.Namespace) -> int:
    import logging
    import signal
    import sys

    from app.formats.jsontext import dumps_json, finite_json
    from app.line.launch import hold_state, json_logs, serving
    from app.line.statedir import StateDir
    from app.sim.line_records import WindowRecord
    from app.sim.line_run import SimulatedLineRun
    from app.sim.shift_report import time_text
    from app.sim.world_record import simulated_world

    cfg = _cell(args)
    state_dir = Path(args.state_dir or cfg.service.state_dir)
    plan = Path(args.plan) if args.plan else _existing(StateDir(state_dir).plan)
    # the cell file `_cell` read from the state directory (a commissioned one), if it did
    commissioned = None
    if args.cell is None and args.state_dir:
        commissioned = _existing(StateDir(state_dir).cell)
    # as commissioned (the cell file), as the directory's first run recorded, or as told
    seed = sim_seed(args.seed, cfg, commissioned)
    geometric = bool(args.geometric or cfg.simulation.geometric)
    paths = StateDir(state_dir)
    if commissioned is None:
        seed, geometric = simulated_world(paths, args.seed, args.geometric, (seed, geometric))
    if plan is not None and not plan.is_file():
        raise InputError("plan file not found", file=plan)
    batch = args.windows is not None
    lines = logging.getLogger(SIM_LOGGER)  # the simulation's own JSON lines on stdout

    def progress(r: WindowRecord) -> None:
        # (whether its bodies are suspect is known once the run ended, as an interval may reach
        # back: the service's suspect_interval events say it as it happens)
        data = {k: v for k, v in r.__dict__.items() if k != "suspect"}
        lines.info("sim_window", extra={"event": "sim_window", "data": finite_json(data)})

    group = str(cfg.service.operators_group)
    handler: logging.Handler | None = None
    if not args.json:  # the service's log too, unless a batch run (its summary says it all)
        handler = json_logs(logger=SIM_LOGGER if batch else "rvis")
    try:
        with (
            hold_state(state_dir, group),
            _features(state_dir, cfg, not args.no_bodies),
            _recorded(paths, seed, geometric),
            SimulatedLineRun(
                cfg,
                state_dir,
                seed=seed,
                geometric=geometric,
                plan=plan,
                sensor_model=None if geometric else _sensor_model(args, state_dir),
                # a person watches a run without --windows: paced; a counted run as fast as it can
                pace=None if batch else cfg.simline.scale,
                waiting=say_waiting,
                bodies=not args.no_bodies,
                attended=True,  # `rvis ctl reset` on its socket clears a FAULT
            ) as sim,
        ):
            with serving(sim.service):
                if not args.json:
                    print(
                        f"rvis run --sim: seed {seed}, "
                        f"{'geometric' if geometric else 'rendered'} measurements, "
                        f"{time_text(sim.pace)}, socket {StateDir(state_dir).socket}",
                        file=sys.stderr,
                        flush=True,
                    )
                previous = signal.signal(signal.SIGTERM, lambda *_: sim.service.stop())
                try:
                    summary = sim.run_windows(
                        args.windows or 10**9, on_window=None if args.json else progress
                    )
                except KeyboardInterrupt:
                    sim.mark_suspect()
                    summary = sim.summary
                    # the parameters in force when stopped, against the truth then
                    summary.true_rmse_final_mm = sim.true_rmse_mm(sim.service.x)
                finally:
                    signal.signal(signal.SIGTERM, previous)
            code = sim.service.exit_code
        if code:
            return _exit(code)
        if args.json:
            print(dumps_json(summary.to_json()))
        elif batch:
            doc = {k: v for k, v in summary.to_json().items() if k != "timeline"}
            lines.info("sim_summary", extra={"event": "sim_summary", "data": finite_json(doc)})
            print(_summary_text(summary), file=sys.stderr)
    finally:
        if handler is not None:
            logging.getLogger(SIM_LOGGER if batch else "rvis").removeHandler(handler)
    return 0


@contextlib.contextmanager
def _features(state_dir: Path, cfg: Any, bodies: bool) -> Iterator[None]:
    """The simulated part type's feature plan in the state directory, when it has none (held:
    written under the state's lock): the simulated line measures its bodies by default, as
    `rvis commission --sim` leaves it; `--no-bodies` (bodies False) writes none."""
    from app.sim.part import ensure_features

    if bodies:
        ensure_features(state_dir, cfg)
    yield


@contextlib.contextmanager
def _recorded(paths: Any, seed: int, geometric: bool) -> Iterator[None]:
    """Under the state's lock: a new directory records the simulated cell it runs
    (app/sim/world_record.py)."""
    from app.sim.world_record import record_world

    record_world(paths, seed, geometric)
    yield


#: The logger of `rvis run --sim`'s own lines (sim_window, sim_summary), JSON on stdout.
SIM_LOGGER = "rvis.sim.run"


def _summary_text(s: Any) -> str:
    """A batch run's summary (app.sim.line_records.SimRunSummary) in words, for a person."""
    return (
        f"{s.windows} windows, {s.measurements} measurements stored ({s.rejected} rejected), "
        f"{s.overruns} overruns, {s.withdrawn} withdrawn; calibrations applied "
        f"{s.calibrations_applied}, rejected {s.calibrations_rejected}; alarms "
        f"{len(s.alarms)}{': ' + '; '.join(s.alarms[:5]) if s.alarms else ''}; true RMSE "
        f"{s.true_rmse_start_mm:.4f} mm at the start, {s.true_rmse_final_mm:.4f} mm at the end"
        + (f"; held for maintenance: {s.maintenance}" if s.maintenance else "")
        + (_bodies_text(s) if s.bodies else "")
    )


def _bodies_text(s: Any) -> str:
    """The bodies a batch run measured, for a person (`rvis results list`: each one)."""
    again = f", {s.bodies_reevaluated} evaluated again" if s.bodies_reevaluated else ""
    return (
        f"; {s.bodies} bodies measured: {s.bodies_nok} nok, {s.bodies_undecided} with a value"
        f" undecided within its U95{again} (`rvis results list`)"
    )
