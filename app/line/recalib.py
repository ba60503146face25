"""Recalibration: rolling measurement set -> identification in a worker process -> gates.

The set is the last `rolling_size` good measurements before the `holdout_size` most recent ones
(only measurements after a jump's onset while one is in hand); it must hold every sphere
and every configuration of the schedule. The identification (calib.identify, starting from the
parameters in force) runs in a separate process, so the cycle never waits for it; `poll()`
collects the outcome between windows. On the simulated line's virtual time (`cost_s` and the
service's `clock`) the identification has a modelled cost: its outcome is seen exactly when the
clock passes its submission + `cost_s` (waiting for the worker then, if it is not done yet), so
when a calibration lands does not depend on how fast the machine computed it. The gates
(`check_candidate`, the one place to fold into calib.gates later): the calib.gates checks
(converged, finite, rank, RMS <= max_rms_mm, condition, bounded change from the parameters in
force) plus "better than the parameters in force on the held-out measurements" (RMS ratio <=
max_holdout_ratio).
"""

from __future__ import annotations

import signal
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import Executor, Future, ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from multiprocessing import resource_tracker
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.config.line import RecalibSettings
from app.formats.params import to_json
from app.threads import exit_with_parent, forkserver_context
from calib.errors import CalibError
from calib.gate_limits import Gates
from calib.gates import check_identification
from calib.identify import (
    IdentificationResult,
    Measurements,
    identify,
    posterior_result,
    residuals,
)
from calib.model import SystemModel
from calib.uncertainty import shown_worse
from calib.validation import rmse
from drivers.clock import Clock

F64 = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class Posterior:
    """The one estimator's posterior (calib.cellstate): the full parameter vector `x` and the
    covariance `cov` of its `active` parameters, the version in force's prior and every
    measurement since folded in."""

    x: F64
    active: tuple[str, ...]
    cov: F64


@dataclass(frozen=True, eq=False)
class RecalJob:
    """Everything the worker needs (picklable). With `posterior` the candidate is the
    estimator's (the cell tracked as one state: no measurement's information is dropped at
    the rolling set's edge, and a configuration measured again is not new evidence about the
    parameters); without (the measurements after a jump's onset, where the version's prior no
    longer holds), the rolling set's identification."""

    model: SystemModel
    x_current: F64
    train: Measurements
    holdout: Measurements
    gates: Gates
    max_nfev: int
    first_id: int
    last_id: int
    posterior: Posterior | None = None


@dataclass(frozen=True, eq=False)
class RecalOutcome:
    """The candidate and its gates: `passed` with no failures, else the reasons."""

    passed: bool
    failures: tuple[str, ...]
    x: F64 | None
    document: dict[str, Any] | None
    rms_mm: float | None
    holdout_rms_mm: float | None
    current_holdout_rms_mm: float
    n_measurements: int
    first_id: int
    last_id: int


def as_measurements(rows: Sequence[Mapping[str, Any]], spheres: Mapping[str, F64]) -> Measurements:
    """Stored measurement rows -> calib Measurements against the spheres' known centres, with
    the cell temperatures when every row has one."""
    temps = [r.get("temp_c") for r in rows]
    return Measurements(
        np.array([r["q_deg"] for r in rows], dtype=float).reshape(-1, 6),
        np.array([r["c_sensor_mm"] for r in rows], dtype=float).reshape(-1, 3),
        np.array([spheres[r["target"]] for r in rows], dtype=float).reshape(-1, 3),
        tuple(str(r["target"]) for r in rows),
        None if not rows or None in temps else np.array(temps, dtype=float),
    )


def select_rolling(
    rows: Sequence[Mapping[str, Any]], n_slots: int, targets: Sequence[str], s: RecalibSettings
) -> tuple[list[Mapping[str, Any]], list[Mapping[str, Any]]] | None:
    """(training rows, held-out rows) from good measurement rows in id order, or None when the
    rolling set is not complete (too few, or a sphere or a schedule slot missing)."""
    if len(rows) < s.rolling_n + s.holdout_size:
        return None
    holdout = list(rows[len(rows) - s.holdout_size :])
    train = list(rows[len(rows) - s.holdout_size - s.rolling_n : len(rows) - s.holdout_size])
    if {r["target"] for r in train} < set(targets):
        return None
    if len({r["slot"] for r in train}) < min(n_slots, s.rolling_n):
        return None
    return train, holdout


def rms_mm(model: SystemModel, x: F64, data: Measurements) -> float:
    return rmse(residuals(model, x, data))


def check_candidate(result: IdentificationResult, job: RecalJob) -> tuple[list[str], float, float]:
    """The gates of a candidate: (failures, candidate held-out RMS, current held-out RMS)."""
    report = check_identification(result, job.x_current, job.gates)
    failures = list(report.failures)
    r_cand = residuals(job.model, result.x, job.holdout)
    r_cur = residuals(job.model, job.x_current, job.holdout)
    cand, cur = rmse(r_cand), rmse(r_cur)
    e_cand, e_cur = np.linalg.norm(r_cand, axis=1), np.linalg.norm(r_cur, axis=1)
    ratio = job.gates.max_holdout_ratio
    # decided on the evidence: worse only when the held-out points show it (a paired test)
    if ratio is not None and not cand <= ratio * cur and shown_worse(e_cand, e_cur):
        failures.append(
            f"held-out RMS {cand:.4f} mm shown worse than the parameters in force"
            f" ({cur:.4f} mm; paired test at 95 % on {len(e_cand)} held-out measurements)"
        )
    return failures, cand, cur


def run_recalibration(job: RecalJob) -> RecalOutcome:
    """The candidate (the estimator's posterior, else the rolling set's identification) and
    its gates (runs in the worker process)."""
    cur = rms_mm(job.model, job.x_current, job.holdout)
    n = len(job.train)
    try:
        if job.posterior is not None:
            post = job.posterior
            result = posterior_result(
                job.model, job.train, post.x, post.active, post.cov, job.x_current
            )
        else:
            result = identify(job.model, job.train, x0=job.x_current, max_nfev=job.max_nfev)
    except CalibError as exc:
        failure = f"identification failed: {exc}"
        return RecalOutcome(
            False, (failure,), None, None, None, None, cur, n, job.first_id, job.last_id
        )
    failures, cand, cur = check_candidate(result, job)
    report = check_identification(result, job.x_current, job.gates)
    doc = to_json(
        job.model,
        result,
        report,
        {
            "source": "rvis run",
            "ids": [job.first_id, job.last_id],
            "candidate": "rolling" if job.posterior is None else "posterior",
        },
    )
    return RecalOutcome(
        not failures,
        tuple(failures),
        result.x,
        doc,
        result.rms_mm,
        cand,
        cur,
        n,
        job.first_id,
        job.last_id,
    )


def _ready() -> None:
    """A job that does nothing: the worker is up."""


STOP_SIGNALS = {signal.SIGTERM, signal.SIGINT}


def _ignore_stop_signals() -> None:
    """In the worker: SIGTERM and SIGINT are the service's to handle (see `stop_signals_held`);
    the service ends the worker itself (`Recalibrator.close`), and a service that dies takes it
    along (`exit_with_parent`)."""
    for sig in STOP_SIGNALS:
        signal.signal(sig, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
    exit_with_parent()


@contextmanager
def stop_signals_held() -> Iterator[None]:
    """Hold SIGTERM and SIGINT in this thread while the pool starts its processes, so that the
    forkserver, the resource tracker and the worker start with them blocked (a signal mask is
    inherited). A supervisor's stop (systemd signals the whole control group) or Ctrl-C in a
    terminal (the whole process group) then reaches only the service: a forkserver or worker
    dying of it would break the pool under a calibration in flight and turn a routine stop
    into an internal error. A signal for the service that comes meanwhile is delivered when
    the mask is restored."""
    # the resource tracker blocks and then UNBLOCKS these signals around its own start: it
    # starts first, or it would undo the mask before the forkserver starts
    resource_tracker.ensure_running()
    old = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def process_executor() -> Executor:
    """One worker process (forkserver: no threads or sockets of the service are inherited),
    deaf to the stop signals meant for the service."""
    return ProcessPoolExecutor(
        1,
        mp_context=forkserver_context(__name__),
        initializer=_ignore_stop_signals,
    )


class Recalibrator:
    """Runs one recalibration at a time in the background; `poll()` never blocks, unless a
    modelled cost (`cost_s` sim seconds on `clock`, virtual time) has passed and the worker
    is not done yet."""

    def __init__(
        self,
        executor_factory: Callable[[], Executor] = process_executor,
        *,
        cost_s: float | None = None,
        clock: Clock | None = None,
    ) -> None:
        if (cost_s is None) != (clock is None) or (cost_s is not None and cost_s < 0):
            raise ValueError("a modelled cost needs both cost_s >= 0 and the clock")
        self._factory = executor_factory
        self._executor: Executor | None = None
        self._future: Future[RecalOutcome] | None = None
        self.cost_s, self._clock = cost_s, clock
        self._ready_t = 0.0  # the clock time its outcome is seen at (modelled cost)

    @property
    def busy(self) -> bool:
        return self._future is not None

    def prestart(self) -> None:
        """Start the worker now rather than with the first job (the simulated line: its start-up
        then overlaps the first windows instead of the first identification)."""
        with stop_signals_held():
            if self._executor is None:
                self._executor = self._factory()
            self._executor.submit(_ready)

    def submit(self, job: RecalJob) -> bool:
        """Start `job` unless one is running; True if started."""
        if self._future is not None:
            return False
        with stop_signals_held():  # the processes it starts inherit the mask
            if self._executor is None:
                self._executor = self._factory()
            self._future = self._executor.submit(run_recalibration, job)
        if self._clock is not None and self.cost_s is not None:
            self._ready_t = self._clock.monotonic() + self.cost_s
        return True

    def poll(self) -> RecalOutcome | None:
        """The finished outcome, once; None while running or idle. With a modelled cost: None
        until the clock has passed it, then the outcome (waiting for the worker if need be)."""
        if self._future is None:
            return None
        if self._clock is not None:
            if self._clock.monotonic() < self._ready_t:
                return None
        elif not self._future.done():
            return None
        return self._take()

    def _take(self) -> RecalOutcome:
        assert self._future is not None
        future, self._future = self._future, None
        return future.result()

    def wait(self, timeout_s: float) -> RecalOutcome | None:
        """Block until the running job is done (tests and shutdown only), whatever its
        modelled cost."""
        if self._future is None:
            return None
        self._future.exception(timeout=timeout_s)
        return self._take()

    def close(self) -> None:
        if self._executor is not None:
            self._executor.shutdown(wait=True, cancel_futures=True)
            self._executor = None
