"""The information matrix of a measurement plan and how a candidate configuration changes it
(the shared engine of calib.detmax's searches and calib.ioptimal's workspace criterion).

Each configuration contributes a 3-row block G_c (3, L) of the column-scaled identification
Jacobian; the information of a selection S with fixed configurations F is

    M(S) = lambda I + sum_{c in F} G_c^T G_c + sum_{c in S} G_c^T G_c

with a tiny ridge lambda so that the partial plans of the first spheres (rank < L) still
compare. `Information` evaluates a criterion (O1..O5, as log values to maximise) after adding
each candidate of a pool or removing each chosen block: O1 by the matrix determinant lemma for
every candidate at once, O2..O5 by the exact spectrum on a shortlist (see calib.detmax).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator

import numpy as np
from numpy.typing import NDArray
from scipy.linalg.lapack import dpotrf, dtrtri

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

RIDGE = 1e-6
#: Candidates of a spectral criterion evaluated exactly per sweep (the rest by their gains).
SHORTLIST = 256
#: Candidates per chunk of a determinant-lemma sweep (W of a chunk fits in cache).
GAIN_CHUNK = 1024
#: A map over chunk starts (the builtin, or a thread pool's).
ChunkMap = Callable[[Callable[[int], None], Iterable[int]], Iterator[None]]


def scaled_blocks(J_blocks: F64, d: F64) -> F64:
    """The column-scaled blocks J * d (M, 3, L), as a view of an (L, 3, M) array: the layout
    of `Information.GT`, which then needs no second copy (on the full grid each is ~100 MB:
    a fresh array of that size costs its page faults)."""
    M, _, L = J_blocks.shape
    GT3 = np.empty((L, 3, M))
    np.multiply(J_blocks.transpose(2, 1, 0), d[:, None, None], out=GT3)
    out: F64 = GT3.transpose(2, 1, 0)
    return out


class Information:
    """The information matrix of fixed blocks plus a selection, with its inverse."""

    def __init__(self, G: F64, G_fixed: F64, criterion: str, rank: int) -> None:
        L = G.shape[2]
        self.G = G
        # (L, 3M): the candidates' first rows, then their second rows, then their third (G
        # as `scaled_blocks` makes it is a view of such an array: no copy)
        m = G.shape[0]
        GT3 = G.transpose(2, 1, 0)
        if GT3.flags.c_contiguous:
            self.GT = GT3.reshape(L, 3 * m)
        else:
            self.GT = np.empty((L, 3 * m))
            for r in range(3):
                self.GT[:, r * m : (r + 1) * m] = G[:, r, :].T
        self.criterion = criterion
        self.rank = rank
        self.M0 = RIDGE * np.eye(L) + np.einsum("kil,kim->lm", G_fixed, G_fixed)
        self.sweeps = 0
        self.all_rows = np.arange(G.shape[0], dtype=np.int64)
        self.chunk_map: ChunkMap = map  # over chunks of candidates (a thread pool's map)
        self._recent: dict[tuple[int, ...], F64] = {}  # whole-pool sweeps by selection

    def matrix(self, sel: list[int]) -> F64:
        Gs = self.G[sel]
        M: F64 = self.M0 + np.einsum("kil,kim->lm", Gs, Gs)
        return M

    def log_value(self, M: F64) -> float:
        if self.criterion == "O1":
            return float(np.linalg.slogdet(M)[1])
        lam = np.asarray(np.linalg.eigvalsh(M), dtype=np.float64)[None, :]
        return float(self._spectral(lam)[0])

    def _spectral(self, lam: F64) -> F64:
        """Log criterion from eigenvalues (B, L) ascending."""
        sig = np.sqrt(np.clip(lam[:, ::-1][:, : self.rank], RIDGE, None))
        s1, sr = sig[:, 0], sig[:, -1]
        out: F64
        if self.criterion == "O2":
            out = np.log(sr / s1)
        elif self.criterion == "O3":
            out = np.log(sr)
        elif self.criterion == "O4":
            out = np.log(sr**2 / s1)
        else:  # O5
            out = -np.log(np.sum(1.0 / sig, axis=1))
        return out

    def if_added(self, sel: list[int], M: F64, pool: I64) -> F64:
        """Log criterion after adding each candidate of pool (P,) to sel (a fresh array).

        The searches ask again for selections they swept just before (a failed excursion is
        retried one level deeper from the same start; after a swap, the exchange sweeps the
        same rest again): the last few whole-pool sweeps are kept by selection, in order, so
        a repeat returns the very same values."""
        key = tuple(sel) if pool is self.all_rows else None
        if key is not None and key in self._recent:
            return self._recent[key].copy()
        values = self._if_added(sel, M, pool)
        if key is not None:
            if len(self._recent) >= 8:
                self._recent.pop(next(iter(self._recent)))
            self._recent[key] = values.copy()
        return values

    def _if_added(self, sel: list[int], M: F64, pool: I64) -> F64:
        self.sweeps += 1
        gains = self._gains(M, pool, +1.0)
        base = float(np.linalg.slogdet(M)[1])
        if self.criterion == "O1":
            out: F64 = base + gains
            return out
        Gp = self.G[pool]
        _, vec = np.linalg.eigh(M)
        weak = vec[:, -self.rank]  # the weakest observable direction
        first_order = np.sum((Gp @ weak) ** 2, axis=1)
        short = np.union1d(np.argsort(-gains)[:SHORTLIST], np.argsort(-first_order)[:SHORTLIST])
        values = np.full(pool.size, -np.inf)
        Ms = M + np.einsum("kil,kim->klm", Gp[short], Gp[short])
        values[short] = self._spectral(np.linalg.eigvalsh(Ms))
        return values

    def _gains(self, M: F64, rows: I64, sign: float) -> F64:
        """log det(I_3 + sign G_c M^-1 G_c^T) for the blocks `rows` (matrix determinant lemma):
        with M = C C^T (Cholesky), W_r = C^-1 G_r^T (one product with the 30 x 30 inverse factor
        for all three rows of every candidate) and the six distinct entries of W^T W. In
        chunks of candidates, so that W stays in cache (a fresh (L, 3M) temporary per sweep
        costs more in memory traffic and page faults than the products)."""
        C_inv = inverse_cholesky(M)
        n_all = self.G.shape[0]
        k = rows.size
        if k == n_all:
            B, offset = self.GT, n_all
        else:
            B, offset = self.GT[:, np.concatenate([rows, rows + n_all, rows + 2 * n_all])], k
        out = np.empty(k)

        def chunk(a: int) -> None:
            b = min(a + GAIN_CHUNK, k)
            W = [C_inv @ B[:, r * offset + a : r * offset + b] for r in range(3)]
            out[a:b] = log_det3(W, sign)

        mapper = self.chunk_map if k > 4 * GAIN_CHUNK else map
        for _ in mapper(chunk, range(0, k, GAIN_CHUNK)):
            pass
        return out

    def best_exchange(self, sel: list[int], floor: float) -> tuple[float, int, int]:
        """The best single exchange (member k of sel out, candidate j in) whose log criterion
        exceeds `floor`: (value, k, j), the first k and j of equal values; (floor, -1, -1)
        when none does. O1 in one pass over the candidates (`_best_exchange_o1`), the others
        by a sweep per member."""
        if self.criterion == "O1":
            return self._best_exchange_o1(sel, floor)
        return self._best_exchange_by_sweeps(sel, floor)

    def _best_exchange_by_sweeps(self, sel: list[int], floor: float) -> tuple[float, int, int]:
        best = (floor, -1, -1)
        for k in range(len(sel)):
            rest = sel[:k] + sel[k + 1 :]
            values = self.if_added(rest, self.matrix(rest), self.all_rows)
            values[sel] = -np.inf
            j = int(np.argmax(values))
            if values[j] > best[0]:
                best = (float(values[j]), k, j)
        return best

    def _best_exchange_o1(self, sel: list[int], floor: float) -> tuple[float, int, int]:
        """All members' exchanges from one product per chunk. With M = C C^T of sel,
        W_c = C^-1 G_c^T and V_i = C^-1 G_i^T (member i), removing member i turns
        G_c M^-1 G_c^T = W_c^T W_c into W_c^T W_c + Y_ic^T Y_ic, Y_ic = R_i^-1 V_i^T W_c,
        R_i R_i^T = I - V_i^T V_i (Woodbury), and log det M into log det M + log det R_i R_i^T:
        the W of a sweep and a (3 k, L) x (L, P) product instead of a sweep per member. Both
        terms are positive semi-definite and come afresh from this selection's factor (no
        cancellation, nothing carried over). Candidates in sel are never swapped in."""
        self.sweeps += 1
        k, n, L = len(sel), self.G.shape[0], self.GT.shape[0]
        M = self.matrix(sel)
        C_inv = inverse_cholesky(M)
        logdet = float(np.linalg.slogdet(M)[1])
        V = C_inv @ self.GT[:, [r * n + s for r in range(3) for s in sel]]  # (L, 3 k)
        Zt = np.zeros((3 * k, L))
        base = np.full(k, -np.inf)  # log det of M without member i
        for i in range(k):
            Vi = V[:, [i, k + i, 2 * k + i]]
            S = np.eye(3) - Vi.T @ Vi
            if np.linalg.eigvalsh(S)[0] <= 0.0:  # removing it leaves M singular: no swap
                continue
            R_inv = np.linalg.inv(np.linalg.cholesky(S))
            Zt[3 * i : 3 * i + 3] = R_inv @ Vi.T
            base[i] = logdet + float(np.linalg.slogdet(S)[1])
        members = np.asarray(sel, dtype=np.int64)
        found: dict[int, list[tuple[float, int]]] = {}

        def chunk(a: int) -> None:
            b = min(a + GAIN_CHUNK, n)
            W = [C_inv @ self.GT[:, r * n + a : r * n + b] for r in range(3)]
            D = _pair_dots(W)  # the six distinct entries of W_c^T W_c, (6, P)
            Y = [(Zt @ w).reshape(k, 3, b - a) for w in W]  # Y_ic's rows, per member
            E = np.empty((6, k, b - a))  # the entries of Y_ic^T Y_ic, all members at once
            for e, (r, s) in enumerate(_PAIRS):
                np.einsum("iqp,iqp->ip", Y[r], Y[s], out=E[e])
            E += D[:, None, :]
            values = _log_det3_from_entries(E)  # (k, P)
            values[:, members[(members >= a) & (members < b)] - a] = -np.inf
            j = np.argmax(values, axis=1)
            found[a] = [(float(values[i, j[i]]) + base[i], a + int(j[i])) for i in range(k)]

        mapper = self.chunk_map if n > 4 * GAIN_CHUNK else map
        for _ in mapper(chunk, range(0, n, GAIN_CHUNK)):
            pass
        best = (floor, -1, -1)
        for i in range(k):  # members in order, chunks in order: the first of equal values
            for a in range(0, n, GAIN_CHUNK):
                v, j = found[a][i]
                if v > best[0]:
                    best = (v, i, j)
        return best

    def if_removed(self, sel: list[int], M: F64, removable: list[int]) -> F64:
        """Log criterion after removing each of `removable` (positions in sel)."""
        rows = np.array([sel[i] for i in removable], dtype=np.int64)
        Gr = self.G[rows]
        if self.criterion == "O1":
            out: F64 = float(np.linalg.slogdet(M)[1]) + self._gains(M, rows, -1.0)
            return out
        Ms = M - np.einsum("kil,kim->klm", Gr, Gr)
        return self._spectral(np.linalg.eigvalsh(Ms))


def inverse_cholesky(M: F64) -> F64:
    """C^-1 of M = C C^T (lower), straight from LAPACK (numpy.linalg's wrappers cost more
    than the 30 x 30 factorisation itself in the swarm's many small sweeps)."""
    C, info = dpotrf(M, lower=1, clean=1)
    if info == 0:
        C_inv, info = dtrtri(C, lower=1)
    if info != 0:
        raise np.linalg.LinAlgError("information matrix not positive definite")
    out: F64 = C_inv
    return out


#: The six distinct entries (r, r') of a symmetric 3x3 block, in the order used here.
_PAIRS = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


def _pair_dots(W: list[F64]) -> F64:
    """The six distinct entries (in the order of _PAIRS) of W_p^T W_p per column p of the
    three (k, P) blocks W: (6, P)."""
    out = np.empty((6, W[0].shape[1]))
    for i, (a, b) in enumerate(_PAIRS):
        np.einsum("lp,lp->p", W[a], W[b], out=out[i])
    return out


def _log_det3_from_entries(E: F64) -> F64:
    """log det(I_3 + E) for the six distinct entries E (6, ...) of symmetric 3x3 blocks
    (in the order of _PAIRS); -inf where the determinant is not positive."""
    a, b, c = 1.0 + E[0], 1.0 + E[1], 1.0 + E[2]
    d, e, f = E[3], E[4], E[5]
    det = a * (b * c - f * f) - d * (d * c - f * e) + e * (d * f - b * e)
    out: F64 = np.full(det.shape, -np.inf)
    np.log(det, out=out, where=det > 0.0)
    return out


def log_det3(W: list[F64], sign: float) -> F64:
    """log det(I_3 + sign W^T W) per column p of the three (L, P) blocks W; -inf where the
    determinant is not positive."""

    def dot(a: int, b: int) -> F64:
        d: F64 = np.einsum("lp,lp->p", W[a], W[b]) * sign
        return d

    s00, s11, s22, s01, s02, s12 = dot(0, 0), dot(1, 1), dot(2, 2), dot(0, 1), dot(0, 2), dot(1, 2)
    det = (
        (1 + s00) * ((1 + s11) * (1 + s22) - s12**2)
        - s01 * (s01 * (1 + s22) - s12 * s02)
        + s02 * (s01 * s12 - (1 + s11) * s02)
    )
    out: F64 = np.full(det.shape, -np.inf)
    np.log(det, out=out, where=det > 0.0)
    return out
