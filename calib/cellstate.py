"""The cell's state as one estimator: the model's parameters and their covariance, updated by
every sphere measurement, with a generalized likelihood ratio (GLR) test for jumps.

State: the deviation d = x - x_ref of the active parameters from the version in force x_ref,
with covariance P (the version's own covariance as the prior: a new cell is no special case),
and for each configuration measured its unmodelled error u_k (3,): the model's error there,
which a configuration measured again repeats, prior s_u^2 I per coordinate, independent of the
rest. A measurement i (configuration k, centre c_i in the sensor frame, the sphere's known
centre p_i in the part frame) gives the innovation

    v_i = p_i - h(x_ref; q_k, c_i) - H_i d - u_k      H_i = dh/dx_active at x_ref    (3,)

whose covariance over the window of the last measurements is

    Sigma = H P H' + D + sigma^2 I      (H over the whole state: the parameters and u_k)
    sigma = one coordinate of a measurement's own noise (sensor, robot repeatability)
    D_ij  = H_i Q H_j' min(tau_i, tau_j)   the slow drift as a random walk of the parameters
            from the window's start (Q per hour: lengths, angles, the extra terms)

The measurements older than the window are folded into (d, P) by the Kalman update, so the
window holds what a jump test still looks at and the state moves with the slow drift. With the
unmodelled errors as states, a configuration measured again is not new evidence about the
parameters (its repeat shows its u_k), and the change since its previous visit is what a jump
shows. s_u is learned from each configuration's first measurement folded (the moments of its
innovation beyond what P and sigma hold), never below the prior's `unmodelled_mm`.

**Jumps** (Willsky and Jones 1976; Basseville and Nikiforov 1993, ch. 7): a hypothesis is a group
that can move at once (calib.attribution.step_groups: the sensor mount, the fixture / part
frame, each joint zero; and each sphere alone). A jump theta of group g at measurement k adds
G_i theta to every innovation from k on (G_i: the group's Jacobian columns; -I for a sphere that
moved by theta), so for each onset k

    a = G' Sigma^-1 v,  F = G' Sigma^-1 G,  theta = F^+ a,  cov(theta) = F^+,  l = a' F^+ a

is twice the log likelihood ratio of the jump against none, chi-square with rank(F) degrees of
freedom when nothing jumped. **Detection**: the smallest p-value over the hypotheses and onsets
below `false_alarm / tests` (Bonferroni over the tests made at this measurement, so the stated
rate is an upper bound per measurement). **Isolation**: the hypotheses scored by Schwarz's
criterion l - rank ln(m) (m equations after the onset); the best decisive when it leads the
runner-up by `margin` and explains the window (the rest of the statistic plausible at 0.999),
else "several". **Onset**: the argmax of the best hypothesis's l over k. **Estimate**: theta and
its covariance, for the correction.

Pure numerics: nothing here knows the service.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import cho_factor, cho_solve
from scipy.special import chdtrc

from calib.attribution import SEVERAL
from calib.hypotheses import Hypothesis, JumpFit, Verdict, beyond_hypotheses, hypotheses
from calib.model import EXTRA_NAMES, INDEX, SystemModel, unit_of
from calib.uncertainty import chi2_ppf

F64 = NDArray[np.float64]
#: the rest of the window's statistic after the best jump must stay below this chi-square
#: quantile for the jump to explain the window
P_EXPLAINS = 0.999


@dataclass(frozen=True)
class Observation:
    """One sphere measurement: its row `ref` (the caller's id), time `t_s`, the sphere
    `target` and its known centre `p_part_mm` (3,), the configuration `q_deg` (6,), the
    centre in the sensor frame `c_sensor_mm` (3,), the cell temperature `temp_c`."""

    ref: int
    t_s: float
    target: str
    p_part_mm: F64
    q_deg: F64
    c_sensor_mm: F64
    temp_c: float | None = None


@dataclass(frozen=True)
class EstimatorSettings:
    """sigma_mm: one coordinate of a measurement's own noise (sensor, robot repeatability);
    unmodelled_mm: the prior of s_u (one coordinate of the model's error at a configuration),
    estimated online from the innovations when `learn_unmodelled`; drift_mm_per_h,
    drift_rad_per_h, drift_extra_per_h: the random walk's standard deviation per sqrt(hour) of
    lengths, angles and the extra terms; window: measurements the jump test looks at;
    false_alarm: the rate per measurement of a detection when nothing jumped; margin: the
    Schwarz score by which the best hypothesis must lead the runner-up (2 ln 20: strong)."""

    sigma_mm: float = 0.02
    unmodelled_mm: float = 0.03
    learn_unmodelled: bool = True
    drift_mm_per_h: float = 0.02
    drift_rad_per_h: float = 1e-5
    drift_extra_per_h: float = 0.0
    window: int = 36
    false_alarm: float = 1e-5
    margin: float = 2.0 * math.log(20.0)

    def __post_init__(self) -> None:
        if not (self.sigma_mm > 0.0 and self.unmodelled_mm >= 0.0 and self.window >= 2):
            raise ValueError("sigma_mm must be > 0, unmodelled_mm >= 0, window >= 2")
        if not 0.0 < self.false_alarm < 1.0 or self.margin < 0.0:
            raise ValueError("false_alarm must be in (0, 1), margin >= 0")


@dataclass
class _Row:
    obs: Observation
    v0: F64  # p - h(x_ref) (3,)
    H: F64  # (3, L) active columns
    G: dict[str, F64] = field(default_factory=dict)  # hypothesis -> (3, k)
    slot: int = 0


class CellState:
    """The estimator (module docstring) on `model` linearised at the version in force `x_ref`
    (full vector) with the covariance `P0` of its `active` parameters."""

    def __init__(
        self,
        model: SystemModel,
        x_ref: ArrayLike,
        active: Sequence[str],
        P0: ArrayLike,
        targets: Sequence[str],
        settings: EstimatorSettings | None = None,
        t0_s: float | None = None,
    ) -> None:
        self.model = model
        self.x_ref = np.asarray(x_ref, float).copy()
        self.active = tuple(active)
        self.settings = settings or EstimatorSettings()
        P = np.asarray(P0, float)
        if P.shape != (len(self.active), len(self.active)):
            raise ValueError(f"P0 must be {len(self.active)}x{len(self.active)}")
        # the state: the parameters' deviation, then each configuration's unmodelled error
        self.L = len(self.active)
        self.P = 0.5 * (P + P.T)
        self.d = np.zeros(self.L)
        self.hyps = hypotheses(model, targets)
        self.beyond = beyond_hypotheses(model)
        every = self.hyps + self.beyond
        self._extra = tuple(sorted({p for h in every for p in h.params} - set(self.active)))
        self.q_per_h = np.array([self._drift_sd(n) ** 2 for n in self.active])
        # the time (d, P) describe (None: the first measurement's)
        self.t_s = t0_s
        self.rows: list[_Row] = []
        self._window_memo: tuple[Any, ...] | None = None  # `_window`'s, `_memo`
        self._posterior_memo: tuple[Any, ...] | None = None
        self._slots: list[F64] = []
        self.s_u_mm = self.settings.unmodelled_mm
        self._moments: list[float] = []  # first visits' estimates of s_u^2 (no jump)
        self._folded: set[int] = set()  # configurations with a measurement in the state

    # -- the state ----------------------------------------------------------------------------
    @property
    def x(self) -> F64:
        """The estimate of the full parameter vector now (the window's measurements included)."""
        return self.estimate()[0]

    def estimate(self) -> tuple[F64, F64]:
        """The full parameter vector now and the covariance of the active parameters (the
        posterior with the window's measurements included), from one posterior."""
        d, P = self.posterior()
        x = self.x_ref.copy()
        x[[INDEX[n] for n in self.active]] += d[: self.L]
        return x, P

    def _drift_sd(self, name: str) -> float:
        s = self.settings
        if name in EXTRA_NAMES:
            return s.drift_extra_per_h
        return s.drift_mm_per_h if unit_of(name) == "mm" else s.drift_rad_per_h

    def _slot(self, q_deg: F64) -> int:
        """The configuration's index; a new one joins the state with its unmodelled error
        (prior s_u^2 per coordinate, independent of everything else)."""
        for k, q in enumerate(self._slots):
            if np.allclose(q, q_deg, atol=1e-6):
                return k
        self._slots.append(q_deg.copy())
        n = len(self.d)
        P = np.zeros((n + 3, n + 3))
        P[:n, :n] = self.P
        P[n:, n:] = self.s_u_mm**2 * np.eye(3)
        self.P, self.d = P, np.r_[self.d, np.zeros(3)]
        return len(self._slots) - 1

    def _H(self, row: _Row) -> F64:
        """The row's Jacobian on the whole state (3, L + 3 K)."""
        H = np.zeros((3, len(self.d)))
        H[:, : self.L] = row.H
        k = self.L + 3 * row.slot
        H[:, k : k + 3] = np.eye(3)
        return H

    def add(self, obs: Observation, test: bool = True) -> Verdict | None:
        """One measurement: into the window (the oldest folded into the state beyond it), and
        the jump test on the window (`test`; a replay tests its last one only)."""
        row = self._row(obs)
        self.t_s = self._t0(obs.t_s)
        self.rows.append(row)
        while len(self.rows) > self.settings.window:
            self._fold(self.rows.pop(0))
        return self.test() if test else None

    def _row(self, obs: Observation) -> _Row:
        names = self.active + self._extra
        temp = None if obs.temp_c is None else np.array([float(obs.temp_c)])
        p, J = self.model.point_and_jacobian(
            self.x_ref, obs.q_deg.reshape(1, 6), obs.c_sensor_mm.reshape(1, 3), names, temp
        )
        v0 = np.asarray(obs.p_part_mm, float) - p[0]
        Jn = J[0]
        col = {n: k for k, n in enumerate(names)}
        G: dict[str, F64] = {}
        for h in self.hyps + self.beyond:
            if h.target is not None:
                G[h.name] = -np.eye(3) if obs.target == h.target else np.zeros((3, 3))
            else:
                G[h.name] = Jn[:, [col[n] for n in h.params]]
        return _Row(obs, v0, Jn[:, : len(self.active)].copy(), G, self._slot(obs.q_deg))

    def _fold(self, row: _Row) -> None:
        """The Kalman update of (d, P) by a measurement leaving the window (its noise white:
        its configuration's unmodelled error is a state)."""
        self._predict(row.obs.t_s)
        if self.settings.learn_unmodelled and row.slot not in self._folded:
            self._learn(row)
        self._folded.add(row.slot)
        H = self._H(row)
        R = self.settings.sigma_mm**2 * np.eye(3)
        S = H @ self.P @ H.T + R
        K = np.linalg.solve(S, H @ self.P).T
        self.d = self.d + K @ (row.v0 - H @ self.d)
        IKH = np.eye(len(self.d)) - K @ H
        self.P = IKH @ self.P @ IKH.T + K @ R @ K.T

    def _t0(self, t_s: float) -> float:
        """The time (d, P) describe (`t_s` when none yet)."""
        return t_s if self.t_s is None else self.t_s

    def _predict(self, t_s: float) -> None:
        dt_h = max(0.0, (t_s - self._t0(t_s)) / 3600.0)
        if dt_h > 0.0:
            self.P[: self.L, : self.L] += np.diag(self.q_per_h * dt_h)
            self.t_s = t_s

    # -- the window -----------------------------------------------------------------------------
    def _same_window(self, memo: tuple[Any, ...] | None) -> bool:
        """`memo` (from `_memo`) was computed on the window and state as they are now: the same
        rows (the objects), time, d and P."""
        return (
            memo is not None
            and memo[0] == (self.t_s, self.d.tobytes(), self.P.tobytes())
            and len(memo[1]) == len(self.rows)
            and all(a is b for a, b in zip(memo[1], self.rows, strict=True))
        )

    def _memo(self, value: Any) -> tuple[Any, ...]:
        return ((self.t_s, self.d.tobytes(), self.P.tobytes()), list(self.rows), value)

    def _window(self) -> tuple[F64, F64, F64]:
        """The window's innovations v (3n,) against the state at its start, their covariance
        Sigma (3n, 3n) under no jump and the stacked H (3n, L + 3K) (computed once for a
        window and state: the test, the posterior and the statement each ask for it)."""
        if self._same_window(self._window_memo):
            assert self._window_memo is not None
            out: tuple[F64, F64, F64] = self._window_memo[2]
            return out
        s = self.settings
        n = len(self.rows)
        H = np.concatenate([self._H(r) for r in self.rows], axis=0)
        v = np.concatenate([r.v0 for r in self.rows]) - H @ self.d
        t0 = self._t0(self.rows[0].obs.t_s)
        tau_h = np.array([max(0.0, (r.obs.t_s - t0) / 3600.0) for r in self.rows])
        Sigma = H @ self.P @ H.T + s.sigma_mm**2 * np.eye(3 * n)
        Hp = H[:, : self.L]
        tmin = np.minimum.outer(tau_h, tau_h)  # (n, n)
        Sigma += ((Hp * self.q_per_h) @ Hp.T) * np.kron(tmin, np.ones((3, 3)))
        out = (v, 0.5 * (Sigma + Sigma.T), H)
        for a in out:
            a.flags.writeable = False
        self._window_memo = self._memo(out)
        return out

    def posterior(self) -> tuple[F64, F64]:
        """The parameters' (d, P) given the window's measurements too (no jump)."""
        L = self.L
        if not self.rows:
            return self.d[:L], self.P[:L, :L]
        if not self._same_window(self._posterior_memo):
            v, Sigma, H = self._window()
            PH = self.P[:L] @ H.T
            K = np.linalg.solve(Sigma, PH.T).T
            self._posterior_memo = self._memo((self.d[:L] + K @ v, self.P[:L, :L] - K @ PH.T))
        assert self._posterior_memo is not None
        d, P = self._posterior_memo[2]
        return d.copy(), P.copy()

    def point_cov_mm2(
        self, q_deg: ArrayLike, c_sensor_mm: ArrayLike, temp_c: float | None = None
    ) -> F64:
        """The covariance (3, 3) [mm^2], in the part frame, of the error of a point seen at
        c_sensor_mm from q_deg through the version in force, as the estimator has it now: the
        parameters' offset d from the version (a bias not corrected, counted as a variance:
        J d d' J'), their covariance J P J' and the unmodelled term s_u^2 I; the measurement's
        own noise is not in it. Its trace / 3 plus sigma^2 is what the statement averages over
        the window's poses (app.line.estimate), here at one pose and in every direction."""
        d, P = self.posterior()
        temp = None if temp_c is None else np.array([float(temp_c)])
        q = np.asarray(q_deg, float).reshape(1, 6)
        c = np.asarray(c_sensor_mm, float).reshape(1, 3)
        J = self.model.point_jacobian(self.x_ref, q, c, self.active, temp)[0]
        b = J @ d
        out: F64 = np.outer(b, b) + J @ P @ J.T + self.s_u_mm**2 * np.eye(3)
        return 0.5 * (out + out.T)

    def test(self) -> Verdict:
        """The GLR test on the window (module docstring)."""
        n = len(self.rows)
        if n == 0:
            return Verdict(False, "", None, None, math.nan, 1.0)
        W, Wv, chi2_all = self._inverse()
        fits = [f for h in self.hyps if (f := self._best_onset(h, W, Wv, range(n))) is not None]
        threshold = self.settings.false_alarm / max(n * len(self.hyps), 1)
        return self._decide(fits, threshold, chi2_all / (3 * n), chi2_all, n)

    def _inverse(self) -> tuple[F64, F64, float]:
        """The window's inverse covariance in blocks (n, 3, n, 3), it times the innovations
        (n, 3), and the innovations' chi-square under no jump."""
        n = len(self.rows)
        v, Sigma, _ = self._window()
        factor = cho_factor(Sigma, lower=True, check_finite=False)
        W = cho_solve(factor, np.eye(3 * n), check_finite=False)
        Wv = cho_solve(factor, v, check_finite=False)
        return W.reshape(n, 3, n, 3), Wv.reshape(n, 3), float(v @ Wv)

    def _best_onset(self, h: Hypothesis, W: F64, Wv: F64, onsets: Sequence[int]) -> JumpFit | None:
        """Hypothesis `h` at the onsets k of the window (at once: with the signature blocks
        G_i (3, d), a_k = sum_{i >= k} G_i' (S^-1 v)_i and F_k = sum_{i, j >= k} G_i' S^-1_ij
        G_j, suffix sums); the onset with the best score (None: none shows it)."""
        n = len(self.rows)
        Gb = np.stack([r.G[h.name] for r in self.rows])  # (n, 3, d)
        C = np.einsum("iad,iajb,jbe->ijde", Gb, W, Gb, optimize=True)  # (n, n, d, d)
        F = C[::-1, ::-1].cumsum(0).cumsum(1)[::-1, ::-1]
        a = np.einsum("iad,ia->id", Gb, Wv)[::-1].cumsum(0)[::-1]  # (n, d)
        seen = np.abs(Gb).reshape(n, -1).max(axis=1)[::-1].cumsum()[::-1] > 0
        ks = list(itertools.takewhile(lambda k: bool(seen[k]), onsets))
        if not ks:
            return None
        # every onset's statistic at once (F_k's eigen-decomposition, its pseudo-inverse's
        # rank and a_k' F_k^+ a_k), then the best onset's fit as _pinv_rank gives it
        Fk = F[ks, ks]
        vals, vecs = np.linalg.eigh(0.5 * (Fk + Fk.transpose(0, 2, 1)))
        keep = vals > RTOL_PINV * np.maximum(vals.max(axis=1, initial=0.0), 1e-300)[:, None]
        ranks = keep.sum(axis=1)
        proj = np.einsum("mde,md->me", vecs, a[ks])
        with np.errstate(divide="ignore", invalid="ignore"):
            llrs = np.where(keep, proj**2 / vals, 0.0).sum(axis=1)
        scores = llrs - ranks * np.log(np.maximum(3 * (n - np.asarray(ks)), 2))
        scores[ranks == 0] = -np.inf
        if not np.isfinite(scores).any():
            return None
        m = int(np.argmax(scores))
        k = ks[m]
        Fp, rank = _pinv_rank(F[k, k])
        llr = float(a[k] @ Fp @ a[k])
        score = llr - rank * math.log(max(3 * (n - k), 2))
        p = float(chdtrc(rank, llr))
        return JumpFit(h, k, self.rows[k].obs.ref, llr, rank, p, score, Fp @ a[k], Fp)

    def held_out_p(self, name: str, onset: int) -> float:
        """Hypothesis `name`'s jump from measurement `onset` on, fitted without the newest
        measurement, predicting that one: the p-value of its innovation (chi-square, 3 dof)
        under the jump, with the jump's, the state's and the measurement's own covariance (0
        when fewer than two measurements follow the onset)."""
        if len(self.rows) - onset < 2:
            return 0.0
        last = self.rows.pop()
        try:
            fit = self.fit(name, onset)
        finally:
            self.rows.append(last)
        if fit is None:
            return 0.0
        L = self.L
        G = last.G[name]
        r = last.v0 - last.H @ self.d[:L] - G @ fit.theta
        k = L + 3 * last.slot
        S = (
            G @ fit.cov @ G.T
            + last.H @ self.P[:L, :L] @ last.H.T
            + self.P[k : k + 3, k : k + 3]
            + self.settings.sigma_mm**2 * np.eye(3)
        )
        return float(chdtrc(3, float(r @ np.linalg.solve(S, r))))

    def group_posterior(self, name: str) -> JumpFit | None:
        """Group `name`'s deviation as the state holds it (its posterior, the window's
        measurements included) as a fit: theta the deviation, cov its covariance, and the
        statistic theta' cov^-1 theta of "it is where the parameters in force put it"."""
        h = next((h for h in self.hyps + self.beyond if h.name == name), None)
        if h is None or h.target is not None or not self.rows:
            return None
        cols = [self.active.index(p) for p in h.params if p in self.active]
        if len(cols) != len(h.params):
            return None
        d, P = self.posterior()
        theta, cov = d[cols], P[np.ix_(cols, cols)]
        inv, rank = _pinv_rank(cov)
        z = float(theta @ inv @ theta)
        p = float(chdtrc(max(rank, 1), z))
        return JumpFit(h, 0, self.rows[0].obs.ref, z, rank, p, 0.0, theta, cov)

    def fit(self, name: str, onset: int = 0) -> JumpFit | None:
        """Hypothesis `name` alone, fitted on the window from measurement `onset` on (a test
        of one hypothesis named before: its p-value needs no correction for the others)."""
        h = next((h for h in self.hyps + self.beyond if h.name == name), None)
        n = len(self.rows)
        if h is None or not 0 <= onset < n:
            return None
        W, Wv, _ = self._inverse()
        return self._best_onset(h, W, Wv, [onset])

    def _decide(
        self, fits: list[JumpFit], threshold: float, nis: float, chi2_all: float, n: int
    ) -> Verdict:
        if not fits:
            return Verdict(False, "", None, None, nis, threshold)
        ranked = sorted(fits, key=lambda f: f.score, reverse=True)
        best = ranked[0]
        second = ranked[1] if len(ranked) > 1 else None
        detected = min(f.p_value for f in fits) < threshold
        if not detected:
            return Verdict(False, "", best, second, nis, threshold, tuple(ranked))
        rest_dof = 3 * n - best.dof
        explains = rest_dof <= 0 or chi2_all - best.llr <= chi2_ppf(P_EXPLAINS, rest_dof)
        decisive = second is None or best.score - second.score >= self.settings.margin
        isolated = best.hypothesis.name if (explains and decisive) else SEVERAL
        return Verdict(True, isolated, best, second, nis, threshold, tuple(ranked))

    def moments(self) -> list[float]:
        """The evidence about s_u^2 so far (to carry into the next version's estimator)."""
        return list(self._moments)

    def learned(self, moments: Sequence[float]) -> None:
        """Evidence about s_u^2 from before (`moments`), taken as this estimator's own."""
        self._moments = [float(m) for m in moments][-4 * self.settings.window :]
        if self._moments and self.settings.learn_unmodelled:
            est = float(np.mean(self._moments))
            self.s_u_mm = math.sqrt(max(self.settings.unmodelled_mm**2, est))

    def _learn(self, row: _Row) -> None:
        """s_u^2 from the innovations by moments, of the measurements that leave the window
        with no jump found in it: a squared innovation less what the state and the noise
        account for (never below the prior's square)."""
        s, L = self.settings, self.L
        resid = row.v0 - row.H @ self.d[:L]
        expect = float(np.trace(row.H @ self.P[:L, :L] @ row.H.T)) + 3 * s.sigma_mm**2
        self._moments.append((float(resid @ resid) - expect) / 3.0)
        self._moments = self._moments[-4 * s.window :]
        est = float(np.mean(self._moments))
        self.s_u_mm = math.sqrt(max(s.unmodelled_mm**2, est))

    def predicted_std_mm(self, fit: JumpFit, q_deg: ArrayLike, c_sensor_mm: ArrayLike) -> float:
        """How well the jump's estimate predicts a point at K views (configurations (K, 6),
        points in the sensor frame (K, 3)): the RMS over them of sqrt(trace(G cov G') / 3)
        [mm per coordinate]; a sphere's move is known where it is measured (its own)."""
        h = fit.hypothesis
        if h.target is not None:
            return float(np.sqrt(np.trace(fit.cov) / 3.0))
        q = np.atleast_2d(np.asarray(q_deg, float))
        c = np.broadcast_to(np.asarray(c_sensor_mm, float), (len(q), 3))
        G = self.model.point_jacobian(self.x_ref, q, c, h.params)
        var = np.einsum("kil,lm,kim->k", G, fit.cov, G) / 3.0
        return float(np.sqrt(np.mean(var)))


#: eigenvalues below this share of the largest count as zero in a pseudo-inverse
RTOL_PINV = 1e-9


def _pinv_rank(F: F64, rtol: float = RTOL_PINV) -> tuple[F64, int]:
    """The pseudo-inverse of a symmetric PSD matrix and its numerical rank."""
    vals, vecs = np.linalg.eigh(0.5 * (F + F.T))
    keep = vals > rtol * max(float(vals.max(initial=0.0)), 1e-300)
    inv = (vecs[:, keep] / vals[keep]) @ vecs[:, keep].T
    return inv, int(keep.sum())
