"""Observability of the identification: rank, condition and the indices O1..O5.

Column scaling (stated because every index depends on it): each column of the stacked
identification Jacobian J (3m x L) is divided by its Euclidean norm, so that the indices are
free of units (mm vs rad) and of the parameters' magnitudes. With unit columns the singular
values satisfy sum(sigma^2) = L, hence O1 <= 1/sqrt(m).

    O1 = (sigma_1 ... sigma_L)^(1/L) / sqrt(m)     Borm & Menq (D-optimality)
    O2 = sigma_L / sigma_1                         Driels & Pathre (inverse condition number)
    O3 = sigma_L                                   Nahvi, Hollerbach & Hayward (E-optimality)
    O4 = sigma_L^2 / sigma_1                       Nahvi & Hollerbach (noise amplification)
    O5 = 1 / (1/sigma_1 + ... + 1/sigma_L)         Sun & Hollerbach (A-optimality)

m is the number of configurations (measurements), each giving 3 rows.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from calib.errors import InsufficientData, NotIdentifiable

F64 = NDArray[np.float64]
INDEX_NAMES = ("O1", "O2", "O3", "O4", "O5")
#: Singular values below RCOND * sigma_1 of the scaled Jacobian count as zero.
RCOND = 1e-9
#: A null-space component above this names its parameter in a redundancy report.
NULL_COMPONENT = 0.1


def column_scaled(J: F64) -> tuple[F64, F64]:
    """(J D, d) with D = diag(d), d_j = 1 / ||J[:, j]|| (0 for an all-zero column)."""
    norms = np.linalg.norm(J, axis=0)
    d = np.where(norms > 0.0, 1.0 / np.where(norms > 0.0, norms, 1.0), 0.0)
    return J * d, d


def index_from_singular_values(name: str, sigma: F64, m: int) -> float:
    """One index from the singular values (descending, all L of them) for m configurations."""
    s = np.asarray(sigma, dtype=float)
    if name == "O1":
        if np.any(s <= 0.0):
            return 0.0
        return float(np.exp(np.mean(np.log(s))) / np.sqrt(m))
    if name == "O2":
        return float(s[-1] / s[0]) if s[0] > 0 else 0.0
    if name == "O3":
        return float(s[-1])
    if name == "O4":
        return float(s[-1] ** 2 / s[0]) if s[0] > 0 else 0.0
    if name == "O5":
        return float(1.0 / np.sum(1.0 / s)) if np.all(s > 0.0) else 0.0
    raise ValueError(f"unknown observability index '{name}' (choose from {', '.join(INDEX_NAMES)})")


def check_index_name(name: str) -> str:
    if name not in INDEX_NAMES:
        raise ValueError(
            f"unknown observability index '{name}' (choose from {', '.join(INDEX_NAMES)})"
        )
    return name


@dataclass(frozen=True)
class Observability:
    """Rank, condition number and O1..O5 of the column-scaled Jacobian."""

    singular_values: F64
    rank: int
    n_params: int
    n_configs: int
    condition: float
    indices: dict[str, float]


def observability(J: F64, n_configs: int) -> Observability:
    """Observability of a stacked identification Jacobian J (3m, L) for m = n_configs."""
    J = np.asarray(J, dtype=float)
    if J.ndim != 2 or J.shape[0] < 1:
        raise InsufficientData("the identification Jacobian is empty")
    Js, _ = column_scaled(J)
    sigma: F64 = np.asarray(np.linalg.svd(Js, compute_uv=False), dtype=np.float64)
    if sigma.size < J.shape[1]:
        sigma = np.concatenate([sigma, np.zeros(J.shape[1] - sigma.size)])
    rank = int(np.sum(sigma > RCOND * sigma[0])) if sigma[0] > 0 else 0
    condition = float(sigma[0] / sigma[-1]) if sigma[-1] > 0 else float("inf")
    values = {n: index_from_singular_values(n, sigma, n_configs) for n in INDEX_NAMES}
    return Observability(sigma, rank, J.shape[1], n_configs, condition, values)


def null_space_groups(J: F64, names: Sequence[str]) -> list[list[str]]:
    """For each null-space direction of the scaled J, the parameters involved in it."""
    Js, _ = column_scaled(np.asarray(J, dtype=float))
    _, sigma, Vt = np.linalg.svd(Js, full_matrices=True)
    sig = np.zeros(Js.shape[1])
    sig[: sigma.size] = sigma
    null = [k for k in range(Js.shape[1]) if sig[k] <= RCOND * max(sig[0], 1e-300)]
    groups: list[list[str]] = []
    for k in null:
        v = Vt[k]
        order = np.argsort(-np.abs(v))
        groups.append([names[j] for j in order if abs(v[j]) > NULL_COMPONENT])
    return groups


def require_full_rank(J: F64, names: Sequence[str]) -> Observability:
    """Observability of J, or NotIdentifiable naming the parameters of the null space."""
    obs = observability(J, max(J.shape[0] // 3, 1))
    if obs.rank < len(names):
        groups = null_space_groups(J, names)
        described = "; ".join("{" + ", ".join(g) + "}" for g in groups)
        raise NotIdentifiable(
            f"identification Jacobian has rank {obs.rank} < {len(names)} parameters: "
            f"not identifiable together: {described}",
            groups,
            obs.rank,
            len(names),
        )
    return obs
