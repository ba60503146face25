"""Choosing n measurement configurations from a sphere's candidates (paper section 4.3).

Each configuration contributes a 3-row block G_c (3, L) of the identification Jacobian, with
columns scaled by fixed factors d (one per parameter: the inverse RMS over the candidate pool
and the fixed configurations of the column's per-configuration norm, so that mm and rad
columns weigh alike). The information matrix of a selection S and the fixed configurations F
(those already chosen for other spheres) is

    M(S) = lambda I + sum_{c in F} G_c^T G_c + sum_{c in S} G_c^T G_c

with a tiny ridge lambda so that the partial plans of the first spheres (rank < L) still
compare. Criteria, each as a log value to maximise:

    O1  log det M                       (D-optimality; monotone in O1 at fixed scaling)
    O2  log sigma_r / sigma_1           O3  log sigma_r
    O4  log sigma_r^2 / sigma_1         O5  -log sum 1/sigma_i   (i <= r)

sigma_i = sqrt of the eigenvalues of M, descending; r is the rank that the fixed
configurations and the whole pool can reach together (so O2..O5 look at the observable
directions while the plan is partial).

O1 uses the matrix determinant lemma for every candidate at once:
det(M + G_c^T G_c) = det M det(I_3 + G_c M^-1 G_c^T), and det(M - G_s^T G_s) likewise:
one (L x L) x (L x 3M) product and M 3x3 determinants per sweep instead of an SVD per
candidate. O2..O5 evaluate the exact spectrum (batched eigvalsh) on a shortlist of the
candidates with the largest determinant gain and the largest first-order gain along the
weakest direction.

Methods: DETMAX (Mitchell 1974) with excursions of growing depth, finished by single exchanges
until none improves (the greedy excursions alone can stop where one exchange still gains);
exchange-add-exchange (Sun & Hollerbach 2008); random selection as the baseline. Seeded
through the rng passed in.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from calib.errors import NoCandidates
from calib.information import GAIN_CHUNK, RIDGE, Information, scaled_blocks
from calib.ioptimal import WeightedInformation, check_weight
from calib.observability import INDEX_NAMES

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

METHODS = ("detmax", "eae", "random")
#: Selection criteria: the observability indices and the workspace criterion (calib.ioptimal).
CRITERIA = (*INDEX_NAMES, "I")
#: An improvement of the log criterion below this ends the search.
TOL = 1e-9


def check_method(name: str) -> str:
    if name not in METHODS:
        raise ValueError(f"unknown selection method '{name}' (choose from {', '.join(METHODS)})")
    return name


def check_criterion(name: str) -> str:
    if name not in CRITERIA:
        raise ValueError(f"unknown criterion '{name}' (choose from {', '.join(CRITERIA)})")
    return name


def column_scale(*J_blocks: F64) -> F64:
    """Scale factors d (L,) from configuration blocks (K, 3, L), of one array or several taken
    together (no concatenated copy): 1 / RMS block column norm."""
    total = sum(np.einsum("kil,kil->l", J, J) for J in J_blocks)
    ms = np.asarray(total, dtype=float) / max(sum(J.shape[0] for J in J_blocks), 1)
    d: F64 = np.where(ms > 0.0, 1.0 / np.sqrt(np.where(ms > 0.0, ms, 1.0)), 0.0)
    return d


@dataclass(frozen=True)
class Selection:
    """The chosen candidate rows `indices` (n,), the log criterion value, how many candidate
    sweeps it took."""

    indices: I64
    log_value: float
    criterion: str
    method: str
    sweeps: int


def select(
    J_candidates: F64,
    n: int,
    rng: np.random.Generator,
    *,
    J_fixed: F64 | None = None,
    criterion: str = "O1",
    method: str = "detmax",
    max_depth: int = 2,
    scale: F64 | None = None,
    start: str = "greedy",
    updates: str = "rank3",
    polish: bool = True,
    threads: int = 1,
    weight: F64 | None = None,
) -> Selection:
    """Choose n of the candidates (blocks J_candidates (M, 3, L)) that maximise the
    criterion together with the fixed blocks J_fixed (F, 3, L). DETMAX and exchange-add-
    exchange start from `start`: "greedy" (n best single additions, deterministic) or
    "random" (n random candidates, as Mitchell's DETMAX). `updates="svd"` evaluates every
    candidate with a full SVD instead of the rank-3 update (the straightforward reference,
    for benchmarks and tests; O1 only). `polish=False` skips DETMAX's final single exchanges
    (the swarm's coarse fitness). `threads` > 1 spreads the sweeps over large candidate sets
    on that many threads (numpy and BLAS release the GIL; the result does not change).
    `weight`: the workspace weight W (L, L) of criterion "I" (calib.ioptimal)."""
    check_criterion(criterion)
    check_method(method)
    J_candidates = np.asarray(J_candidates, dtype=float)
    m_cand, L = J_candidates.shape[0], J_candidates.shape[2]
    if n < 1:
        raise ValueError(f"number of configurations to choose must be >= 1, got {n}")
    if m_cand < n:
        raise NoCandidates(f"{m_cand} candidate configurations, {n} needed")
    J_fix = np.zeros((0, 3, L)) if J_fixed is None else np.asarray(J_fixed, dtype=float)
    d = column_scale(J_fix, J_candidates) if scale is None else scale
    G, G_fix = scaled_blocks(J_candidates, d), J_fix * d
    rank = L
    if criterion not in ("O1", "I"):
        pool_info = np.einsum("kil,kim->lm", G, G) + np.einsum("kil,kim->lm", G_fix, G_fix)
        lam = np.linalg.eigvalsh(pool_info)
        rank = max(1, int(np.sum(lam > 1e-9 * lam[-1])))
    if updates not in ("rank3", "svd"):
        raise ValueError(f"unknown update scheme '{updates}' (choose from rank3, svd)")
    if criterion == "I":
        W = check_weight(weight, L)
        info: Information = WeightedInformation(G, G_fix, W * d[:, None] * d[None, :])
    else:
        info = (_SvdInformation if updates == "svd" else Information)(G, G_fix, criterion, rank)
    if start not in ("greedy", "random"):
        raise ValueError(f"unknown start '{start}' (choose from greedy, random)")
    first = [int(i) for i in rng.choice(m_cand, size=n, replace=False)]
    if threads > 1 and m_cand > 4 * GAIN_CHUNK:
        with ThreadPoolExecutor(max_workers=threads) as pool:
            info.chunk_map = pool.map
            return _run(info, method, start, first, n, max_depth, polish)
    return _run(info, method, start, first, n, max_depth, polish)


def _run(
    info: Information,
    method: str,
    start: str,
    first: list[int],
    n: int,
    max_depth: int,
    polish: bool,
) -> Selection:
    if method == "random":
        sel = first
    elif method == "detmax":
        sel = _greedy(info, n) if start == "greedy" else first
        sel = _detmax(info, sel, max_depth)
        sel = _exchange(info, sel) if polish else sel
    else:
        k = max(1, (n + 1) // 2)
        sel = _eae(info, _greedy(info, k) if start == "greedy" else first[:k], n)
    value = info.log_value(info.matrix(sel))
    return Selection(np.array(sel, dtype=np.int64), value, info.criterion, method, info.sweeps)


class _SvdInformation(Information):
    """The straightforward reference: a full SVD of the stacked scaled Jacobian per candidate
    (log det M = 2 sum log sigma of [sqrt(lambda) I; G_fixed; G_selected; G_candidate])."""

    def __init__(self, G: F64, G_fixed: F64, criterion: str, rank: int) -> None:
        if criterion != "O1":
            raise ValueError("the SVD reference implements O1 only")
        super().__init__(G, G_fixed, criterion, rank)
        L = G.shape[2]
        self.rows0 = np.concatenate([np.sqrt(RIDGE) * np.eye(L), G_fixed.reshape(-1, L)])

    def _logdet_rows(self, blocks: F64) -> float:
        A = np.concatenate([self.rows0, blocks.reshape(-1, self.G.shape[2])])
        sigma = np.linalg.svd(A, compute_uv=False)
        return float(2.0 * np.sum(np.log(sigma)))

    def if_added(self, sel: list[int], M: F64, pool: I64) -> F64:
        self.sweeps += 1
        chosen = self.G[sel]
        return np.array(
            [self._logdet_rows(np.concatenate([chosen, self.G[c : c + 1]])) for c in pool]
        )

    def if_removed(self, sel: list[int], M: F64, removable: list[int]) -> F64:
        return np.array(
            [self._logdet_rows(self.G[[s for j, s in enumerate(sel) if j != i]]) for i in removable]
        )

    def best_exchange(self, sel: list[int], floor: float) -> tuple[float, int, int]:
        return self._best_exchange_by_sweeps(sel, floor)


def _greedy(info: Information, n: int) -> list[int]:
    sel: list[int] = []
    for _ in range(n):
        sel = _add_best(info, sel)
    return sel


def _add_best(info: Information, sel: list[int]) -> list[int]:
    M = info.matrix(sel)
    values = info.if_added(sel, M, info.all_rows)
    values[sel] = -np.inf
    return [*sel, int(np.argmax(values))]


def _remove_best(info: Information, sel: list[int]) -> list[int]:
    """Remove the member whose removal lowers the criterion least."""
    M = info.matrix(sel)
    values = info.if_removed(sel, M, list(range(len(sel))))
    k = int(np.argmax(values))
    return sel[:k] + sel[k + 1 :]


def _detmax(info: Information, sel: list[int], max_depth: int) -> list[int]:
    """Mitchell's DETMAX: excursions that add then remove `depth` points; a failed excursion
    is retried one level deeper; stop when no excursion up to max_depth improves."""
    current = info.log_value(info.matrix(sel))
    for _ in range(200 * len(sel)):
        for depth in range(1, max_depth + 1):
            trial = list(sel)
            for _ in range(depth):
                trial = _add_best(info, trial)
            for _ in range(depth):
                trial = _remove_best(info, trial)
            value = info.log_value(info.matrix(trial))
            if value > current + TOL and sorted(trial) != sorted(sel):
                sel, current = trial, value
                break
        else:
            return sel
    return sel


def _exchange(info: Information, sel: list[int]) -> list[int]:
    """Best single swaps (member out, candidate in) until none improves."""
    current = info.log_value(info.matrix(sel))
    for _ in range(200 * max(len(sel), 1)):
        best = info.best_exchange(sel, current + TOL)
        if best[1] < 0:
            return sel
        sel = [*sel[: best[1]], best[2], *sel[best[1] + 1 :]]
        current = info.log_value(info.matrix(sel))
    return sel


def _eae(info: Information, sel: list[int], n: int) -> list[int]:
    """Exchange-add-exchange: exchange to convergence, add the best, exchange again, until n."""
    sel = _exchange(info, sel)
    while len(sel) < n:
        sel = _exchange(info, _add_best(info, sel))
    return sel


__all__ = ["CRITERIA", "INDEX_NAMES", "METHODS", "Selection", "column_scale", "select"]
