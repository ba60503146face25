"""Errors of the calibration numerics.

    CalibError                 root
    ├── InsufficientData       fewer equations than parameters, empty or malformed arrays
    ├── NotIdentifiable        the identification Jacobian is rank deficient; `groups` names
    │                          the parameters that move together in each null-space direction
    └── PlanningError          measurement planning cannot proceed
        ├── NoCandidates       no configuration sees a sphere (unreachable, all filtered out)
        └── EmptyRegion        the feasible region for the spheres contains nothing

Did-not-converge is not an error: the result objects carry `success`, `status`, `message`.
"""

from __future__ import annotations


class CalibError(ValueError):
    """Root of calib's errors (a ValueError: the caller passed something unusable)."""


class InsufficientData(CalibError):
    """Not enough (or malformed) data for the requested computation."""


class NotIdentifiable(CalibError):
    """Rank-deficient identification: `groups` lists, per null-space direction, the parameter
    names involved (largest component first)."""

    def __init__(self, message: str, groups: list[list[str]], rank: int, n_params: int) -> None:
        self.groups = groups
        self.rank = rank
        self.n_params = n_params
        super().__init__(message)


class PlanningError(CalibError):
    """Measurement planning cannot proceed with these inputs."""


class NoCandidates(PlanningError):
    """No (or too few) reachable configurations see a sphere."""


class EmptyRegion(PlanningError):
    """The feasible region for sphere placement is empty."""
