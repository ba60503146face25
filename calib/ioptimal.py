"""The workspace criterion "I": choose configurations for the accuracy where the system is used.

O1..O5 judge the identification Jacobian alone: how well the parameters are determined in
every direction of parameter space, whether a direction matters to the measurements or not.
What the line (and the paper's validation) sees is the position error at sphere positions
spread over the workspace. With the parameter error's covariance sigma^2 M^-1 (M the
information matrix J^T J of the calibration configurations) the expected squared error at a
workspace view with point Jacobian J_u is sigma^2 trace(J_u M^-1 J_u^T), so its mean over the
workspace is sigma^2 trace(W M^-1) with W = mean J_u^T J_u: the I-optimal (integrated
variance) design criterion, here with W from views drawn over the inspection workspace.

Partial plans (fewer than four spheres, rank r < L): only the directions that the fixed
configurations and the candidates can reach count (W projected onto them); the others no
choice can change.

In DETMAX the criterion is a log value to maximise, -log trace(W M^-1), and a candidate's
effect comes from the Sherman-Morrison-Woodbury identity: with M = C C^T, W_c = C^-1 G_c^T
(L, 3), A_c = W_c^T W_c and B_c = W_c^T K W_c, K = C^-1 W C^-T,

    trace(W (M +- G_c^T G_c)^-1) = trace K -+ trace((I_3 +- A_c)^-1 B_c).

As an index (`i_index`) it is 1 / sqrt(trace(W M^-1)) of the column-scaled blocks: larger is
better, like O1..O5.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from calib.information import GAIN_CHUNK, RIDGE, Information, inverse_cholesky

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]
NAME = "I"


def check_weight(weight: F64 | None, n_params: int) -> F64:
    """The weight W as a symmetric (L, L) array; ValueError when missing or malformed."""
    if weight is None:
        raise ValueError("criterion I needs the workspace weight W (PlanSettings.weight)")
    W = np.asarray(weight, dtype=float)
    if W.shape != (n_params, n_params) or not np.all(np.isfinite(W)):
        raise ValueError(f"workspace weight: expected a finite ({n_params}, {n_params}) matrix")
    out: F64 = 0.5 * (W + W.T)
    return out


def workspace_weight(J_use: F64) -> F64:
    """W = mean over the workspace views of J_u^T J_u, from their blocks (K, 3, L)."""
    J = np.asarray(J_use, dtype=float)
    if J.ndim != 3 or J.shape[0] < 1:
        raise ValueError("workspace weight: no workspace views")
    out: F64 = np.einsum("kil,kim->lm", J, J) / J.shape[0]
    return out


def observable_projector(info: F64, rel_tol: float = 1e-9) -> F64:
    """The projector onto the eigenvectors of `info` with eigenvalue > rel_tol * the largest."""
    lam, vec = np.linalg.eigh(info)
    keep = vec[:, lam > rel_tol * max(float(lam[-1]), 1e-300)]
    out: F64 = keep @ keep.T
    return out


def i_index(J_blocks: F64, weight: F64, rank: int | None = None) -> float:
    """1 / sqrt(trace(W M^+)) of blocks (K, 3, L) over their r largest eigen-directions
    (r = rank, default L); 0 when the blocks reach fewer directions."""
    L = J_blocks.shape[2]
    J = J_blocks.reshape(-1, L)
    norms = np.linalg.norm(J, axis=0)
    d = np.where(norms > 0.0, 1.0 / np.where(norms > 0.0, norms, 1.0), 0.0)
    Js = J * d
    lam, vec = np.linalg.eigh(Js.T @ Js)
    r = L if rank is None else rank
    lam, vec = lam[::-1][:r], vec[:, ::-1][:, :r]
    if lam[-1] <= 1e-12 * max(float(lam[0]), 1e-300):
        return 0.0
    Ws = weight * d[:, None] * d[None, :]
    trace = float(np.sum(np.einsum("li,lm,mi->i", vec, Ws, vec) / lam))
    return 1.0 / np.sqrt(trace) if trace > 0.0 else 0.0


class WeightedInformation(Information):
    """DETMAX's information matrix with the criterion -log trace(W M^-1) (W scaled like the
    blocks and projected onto the directions the pool reaches)."""

    def __init__(self, G: F64, G_fixed: F64, weight_scaled: F64) -> None:
        super().__init__(G, G_fixed, NAME, G.shape[2])
        pool = np.einsum("kil,kim->lm", G, G) + np.einsum("kil,kim->lm", G_fixed, G_fixed)
        P = observable_projector(pool)
        self.W = P @ weight_scaled @ P

    def log_value(self, M: F64) -> float:
        C_inv = inverse_cholesky(M)
        trace = float(np.trace(C_inv @ self.W @ C_inv.T))
        return -np.log(trace) if trace > 0.0 else np.inf

    def _if_added(self, sel: list[int], M: F64, pool: I64) -> F64:
        self.sweeps += 1
        return self._traces(M, pool, +1.0)

    def if_removed(self, sel: list[int], M: F64, removable: list[int]) -> F64:
        rows = np.array([sel[i] for i in removable], dtype=np.int64)
        return self._traces(M, rows, -1.0)

    def _traces(self, M: F64, rows: I64, sign: float) -> F64:
        """-log trace(W (M + sign G_c^T G_c)^-1) for the blocks `rows`, in chunks."""
        C_inv = inverse_cholesky(M)
        K = C_inv @ self.W @ C_inv.T
        base = float(np.trace(K))
        out = np.empty(rows.size)
        for a in range(0, rows.size, GAIN_CHUNK):
            idx = rows[a : a + GAIN_CHUNK]
            R = self.G[idx] @ C_inv.T  # (P, 3, L): W_c^T of every candidate
            Rt = R.transpose(0, 2, 1)
            A = R @ Rt
            B = (R @ K) @ Rt
            S = np.eye(3) + sign * A
            ok = np.linalg.det(S) > 0.0
            change = np.zeros(idx.size)
            if np.any(ok):
                change[ok] = np.trace(np.linalg.solve(S[ok], B[ok]), axis1=1, axis2=2)
            trace = base - sign * change
            vals = np.full(idx.size, -np.inf)
            good = ok & (trace > 0.0)
            vals[good] = -np.log(trace[good])
            out[a : a + idx.size] = vals
        return out


__all__ = ["NAME", "RIDGE", "WeightedInformation", "check_weight", "i_index", "workspace_weight"]
