"""Quality gates of an identification: a result is called a success only when it passes them.

An optimiser that stopped is not yet a calibration. The gates, in the order they are checked:
converged (the optimiser's own status), every value finite, rank equal to the number of
identified parameters, residual RMS <= `max_rms_mm`, column-scaled condition number <=
`max_condition` (Schroer: below 100 for reliable identification), and every parameter within a
bounded change from a reference (the nominal model for an offline identification, the applied
parameters in-line): lengths in mm, angles in rad, per chain piece. The part->base pose is
checked only when a bound is given (offline its guess may be far off; the identification
starts from a closed-form alignment instead). The limits themselves (`Gates`, `OFFLINE`,
`INLINE`) are plain numbers in calib/gate_limits.py.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from calib.gate_limits import Gates
from calib.identify import IdentificationResult
from calib.model import BASE_NAMES, INDEX, SENSOR_NAMES, unit_of

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class GateReport:
    """`passed` and, when not, one short reason per failed gate."""

    passed: bool
    failures: tuple[str, ...]

    @property
    def reason(self) -> str:
        return "; ".join(self.failures) if self.failures else "all quality gates passed"

    def to_json(self) -> dict[str, object]:
        return {"passed": self.passed, "failures": list(self.failures)}


def _limits(name: str, gates: Gates) -> float | None:
    mm = unit_of(name) == "mm"
    if name in BASE_NAMES:
        return gates.max_base_change_mm if mm else gates.max_base_change_rad
    if name in SENSOR_NAMES:
        return gates.max_sensor_change_mm if mm else gates.max_sensor_change_rad
    return gates.max_joint_change_mm if mm else gates.max_joint_change_rad


def change_failures(active: tuple[str, ...], x: F64, x_ref: F64, gates: Gates) -> list[str]:
    """One message per parameter whose change from x_ref exceeds its bound."""
    out = []
    for name in active:
        limit = _limits(name, gates)
        delta = float(x[INDEX[name]] - x_ref[INDEX[name]])
        if limit is not None and abs(delta) > limit:
            if unit_of(name) == "mm":
                out.append(f"{name} changed by {delta:+.3f} mm (limit {limit:g} mm)")
            else:
                out.append(
                    f"{name} changed by {np.degrees(delta):+.4f} deg "
                    f"(limit {np.degrees(limit):g} deg)"
                )
    return out


def check_identification(result: IdentificationResult, x_ref: F64, gates: Gates) -> GateReport:
    """The gates of `result` against the reference parameters `x_ref` (full vector)."""
    failures: list[str] = []
    if not result.success:
        failures.append(f"did not converge: {result.message}")
    values = (result.x, result.std, result.residuals_mm, np.array([result.rms_mm]))
    if not all(np.all(np.isfinite(v)) for v in values):
        failures.append("non-finite values in the result")
        return GateReport(False, tuple(failures))
    obs = result.observability
    if obs.rank < len(result.active):
        failures.append(f"rank {obs.rank} < {len(result.active)} parameters")
    if result.rms_mm > gates.max_rms_mm:
        failures.append(f"residual RMS {result.rms_mm:.4f} mm > max_rms_mm {gates.max_rms_mm:g} mm")
    if not obs.condition <= gates.max_condition:
        failures.append(f"condition number {obs.condition:.1f} > {gates.max_condition:g}")
    changes = change_failures(result.active, result.x, x_ref, gates)
    if len(changes) > 2:
        changes = [f"{len(changes)} parameters beyond their change limits ({changes[0]}, ...)"]
    failures += changes
    return GateReport(not failures, tuple(failures))
