"""Closed-form inverse kinematics of the nominal M-710iC/50, vectorised over flange poses.

Geometry (base frame B = FANUC World, controller angles): the wrist centre W lies d6 = 175 mm
behind the flange along its z axis. In the arm plane turned by J1, with r the signed horizontal
distance of W from the J1 axis and z its height,

    r = 150 + 870 sin J2 + L cos(J3 + delta),   z = 870 cos J2 + L sin(J3 + delta),

L = hypot(1016, 170), delta = atan2(170, 1016): a two-link problem with two elbow branches for
each of the two J1 branches (front and back). The wrist is spherical: with R_3_6 from the arm,
Rx(90) R_3_6 = Rz(theta4) Ry(-theta5) Rz(theta6), two branches (theta5 of either sign). Each
of J1, J3, J4 and J6 also has its +-360 deg turn alternatives where the limits allow.

Singular poses (wrist centre on the J1 axis, theta5 = 0) and unreachable ones give no solution;
the output never holds NaN.

Speed (bench/ik.py): everything is element-wise on contiguous rows of the pose entries, all
eight branches at once by broadcasting over (shoulder, elbow) axes; the angles come from
products and sums of sines and cosines already at hand (no rotation-matrix products, one atan2
per joint and arm branch; the wrist flip is J4 -+ 180, -J5, J6 -+ 180). The whole-turn
alternatives are counted per joint (the limits are a box, so the valid alternatives of a
branch are a product of per-joint ranges, one `pattern` indexing a table of valid turn
combinations), not by testing every combination of turns. Two passes over chunks of poses:
the first computes the branches and counts the solutions of each, the second writes every
solution once into outputs of the exact size. Chunks keep every temporary in cache: with the
turn alternatives the output is ~25 solutions per pose, and large fresh temporaries (page
faults) cost more than the arithmetic. No np.hypot (ten times slower than the square root of
the sum of squares, and nothing here can overflow).
"""

from __future__ import annotations

import functools
import itertools
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calib import robot

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

_A1, _C2, _A3, _D4, _D6 = 150.0, 870.0, 170.0, 1016.0, 175.0
_L = float(np.hypot(_D4, _A3))
_DELTA = float(np.arctan2(_A3, _D4))
_COS_DELTA, _SIN_DELTA = _D4 / _L, _A3 / _L
SINGULAR_TOL = 1e-9
#: Tolerance of the joint-limit test [deg] (as `robot.JointLimits.contains`).
LIMIT_TOL_DEG = 1e-9
#: Number of branches (J1 front/back x elbow x wrist flip); branch code = 4 back + 2 elbow + flip.
N_BRANCHES = 8
#: Poses per chunk of the branch computation.
CHUNK = 2048

_SHOULDER_SIGN = np.array([1.0, -1.0]).reshape(2, 1, 1)
_ELBOW_SIGN = np.array([1.0, -1.0]).reshape(1, 2, 1)
_DEG = 180.0 / np.pi


@dataclass(frozen=True)
class IKSolutions:
    """All solutions of a batch: `q_deg` (M, 6) controller angles, `pose_index` (M,) the index
    of the flange pose each solves, `branch` (M,) an id of the branch (J1 front/back, elbow,
    wrist flip) and the whole-turn alternative: code * n_turns + k, code = 4 back + 2 elbow +
    flip, k the index of the turn combination in `turn_shifts(limits)`."""

    q_deg: F64
    pose_index: I64
    branch: I64

    def for_pose(self, i: int) -> F64:
        """The solutions (K, 6) of pose i."""
        sel: F64 = self.q_deg[self.pose_index == i]
        return sel


def solve(
    T_base_flange: ArrayLike,
    limits: robot.JointLimits | None = None,
    *,
    turn_alternatives: bool = True,
) -> IKSolutions:
    """Every controller-angle solution within the limits for flange poses (N, 4, 4) [mm].

    Solutions come pose by pose (`pose_index` ascending), within a pose by branch id."""
    T = np.asarray(T_base_flange, dtype=float).reshape(-1, 4, 4)
    limits = limits or robot.JointLimits()
    return _solve(T, limits, turn_alternatives)


def _solve(T: F64, limits: robot.JointLimits, turn_alternatives: bool) -> IKSolutions:
    n = T.shape[0]
    table = _turn_table(tuple(limits.lower_deg), tuple(limits.upper_deg), turn_alternatives)
    if table.n_turns == 0:  # a joint whose limits no whole turn of [-180, 180) reaches
        return IKSolutions(np.zeros((0, 6)), np.zeros(0, np.int64), np.zeros(0, np.int64))
    lo = limits.lower_deg - LIMIT_TOL_DEG
    hi = limits.upper_deg + LIMIT_TOL_DEG
    E = np.ascontiguousarray(T.reshape(n, 16).T)  # E[4 i + j] = T[:, i, j], contiguous rows
    # pass 1: the branches of every pose as rows (pose * 8 + code, 6) and how many solutions
    # each row gives (its whole-turn alternatives within the limits)
    rows_q = np.empty((n * N_BRANCHES, 6))
    counts = np.empty(n * N_BRANCHES, dtype=np.int64)
    pattern = np.empty(n * N_BRANCHES, dtype=np.intp)
    for a in range(0, n, CHUNK):
        b = min(a + CHUNK, n)
        r = slice(a * N_BRANCHES, b * N_BRANCHES)
        _count_chunk(E[:, a:b], table, lo, hi, rows_q[r], counts[r], pattern[r])
    # pass 2: every solution written once into outputs of the exact size, chunk by chunk
    ends = np.cumsum(counts)
    m = int(ends[-1]) if n else 0
    q_deg = np.empty((m, 6))
    pose_index = np.empty(m, dtype=np.int64)
    branch = np.empty(m, dtype=np.int64)
    for a in range(0, n * N_BRANCHES, CHUNK * N_BRANCHES):
        b = min(a + CHUNK * N_BRANCHES, n * N_BRANCHES)
        o = slice(int(ends[a - 1]) if a else 0, int(ends[b - 1]))
        _expand_chunk(table, a, rows_q[a:b], counts[a:b], pattern[a:b],
                      q_deg[o], pose_index[o], branch[o])  # fmt: skip
    return IKSolutions(q_deg, pose_index, branch)


def _count_chunk(
    E: F64, table: _TurnTable, lo: F64, hi: F64, rows_q: F64, counts: I64, pattern: NDArray[np.intp]
) -> None:
    """Branches of a chunk of c poses into rows_q (8 c, 6); per row the number of solutions
    and, with several turns, the index of its pattern of valid turns into `table.valid`."""
    c = E.shape[1]
    Z = np.empty((6, 2, 2, 2, c))  # joint, back, elbow, flip, pose
    keep5 = np.empty((2, 2, 2, c), dtype=bool)
    _branches_chunk(E, Z, keep5)
    Z3, keep = Z.reshape(6, N_BRANCHES, c), keep5.reshape(N_BRANCHES, c)
    for j in table.single:
        if table.single_shift_deg[j]:
            Z3[j] += table.single_shift_deg[j]
        keep &= (Z3[j] >= lo[j]) & (Z3[j] <= hi[j])
    rows_q.reshape(c, N_BRANCHES, 6)[...] = Z3.transpose(2, 1, 0)
    if not table.multi:  # one turn combination: a plain range test
        counts.reshape(c, N_BRANCHES)[...] = keep.T
        return
    # per multi-turn joint the valid whole turns are a range [i_min, i_max] of indices into
    # its list of turns; the pair is one code, the codes of all joints one pattern
    code = np.zeros((N_BRANCHES, c))
    for m, j in enumerate(table.multi):
        k0, nk = table.k_first[m], table.n_k[m]
        i_min = np.ceil((lo[j] - Z3[j]) * (1.0 / 360.0)) - k0
        i_max = np.floor((hi[j] - Z3[j]) * (1.0 / 360.0)) - k0
        np.clip(i_min, 0.0, nk, out=i_min)
        np.clip(i_max, -1.0, nk - 1.0, out=i_max)
        code += (i_min * (nk + 1.0) + i_max + 1.0) * table.radix[m]
    code[~keep] = 0.0  # NaN where the input was
    index = code.T.astype(np.intp)
    pattern.reshape(c, N_BRANCHES)[...] = index
    counts.reshape(c, N_BRANCHES)[...] = np.where(keep.T, table.n_valid[index], 0)


def _expand_chunk(
    table: _TurnTable,
    row0: int,
    rows_q: F64,
    counts: I64,
    pattern: NDArray[np.intp],
    q_deg: F64,
    pose_index: I64,
    branch: I64,
) -> None:
    """Write the solutions of a chunk of rows (row0 = index of its first row, a multiple of 8)
    into the output slices."""
    kept = np.flatnonzero(counts)
    if not table.multi:
        np.take(rows_q, kept, axis=0, out=q_deg, mode="clip")  # "raise" buffers `out`
        np.bitwise_and(kept, N_BRANCHES - 1, out=branch)
        np.right_shift(kept + row0, 3, out=pose_index)
        return
    flat = np.flatnonzero(table.valid[pattern[kept]])  # kept row by row, turns ascending
    turn = flat % table.n_turns
    row = np.take(kept, flat // table.n_turns)
    np.take(rows_q, row, axis=0, out=q_deg, mode="clip")  # indices valid
    q_deg += np.take(table.shifts_deg, turn, axis=0)
    np.bitwise_and(row, N_BRANCHES - 1, out=branch)
    branch *= table.n_turns
    branch += turn
    row += row0
    np.right_shift(row, 3, out=pose_index)  # row // N_BRANCHES


@dataclass(frozen=True)
class _TurnTable:
    """How whole-turn alternatives expand under given limits (built once per limits)."""

    n_turns: int  # number of turn combinations (`turn_shifts`)
    shifts_deg: F64  # (n_turns, 6)
    single: tuple[int, ...]  # joints with exactly one possible turn
    single_shift_deg: dict[int, float]
    multi: list[int]  # joints with several possible turns
    k_first: F64  # (m,) lowest turn of each multi joint
    n_k: F64  # (m,) number of possible turns of each multi joint
    radix: F64  # (m,) pattern = sum(code_j * radix_j)
    valid: NDArray[np.bool_]  # (n_patterns, n_turns)
    n_valid: I64  # (n_patterns,) valid turn combinations of each pattern


@functools.lru_cache(maxsize=16)
def _turn_table(
    lower_deg: tuple[float, ...], upper_deg: tuple[float, ...], turn_alternatives: bool
) -> _TurnTable:
    limits = robot.JointLimits(np.array(lower_deg), np.array(upper_deg))
    ks = _turn_ks(limits) if turn_alternatives else [[0]] * 6
    shifts = 360.0 * np.array(list(itertools.product(*ks)), dtype=float).reshape(-1, 6)
    single = tuple(j for j in range(6) if len(ks[j]) == 1)
    multi = [j for j in range(6) if len(ks[j]) > 1]
    # valid[pattern, combination]: outer product over the multi joints (in joint order, so
    # the combinations come in `itertools.product` order) of per-joint tables
    valid = np.ones((1, 1), dtype=bool)
    codes = []
    for j in multi:
        s = len(ks[j])
        i_min, i_max = np.divmod(np.arange((s + 1) ** 2), s + 1)
        i_max = i_max - 1
        idx = np.arange(s)
        vj = (i_min[:, None] <= idx) & (idx <= i_max[:, None])  # ((s+1)^2, s)
        valid = (valid[:, None, :, None] & vj[None, :, None, :]).reshape(
            valid.shape[0] * vj.shape[0], valid.shape[1] * s
        )
        codes.append((s + 1) ** 2)
    if not all(ks):  # a joint no turn brings inside its limits: nothing is ever valid
        valid = np.zeros((1, 0), dtype=bool)
    radix = np.ones(len(multi))
    for m in range(len(multi) - 2, -1, -1):
        radix[m] = radix[m + 1] * codes[m + 1]
    return _TurnTable(
        n_turns=len(shifts),
        shifts_deg=shifts,
        single=single,
        single_shift_deg={j: 360.0 * ks[j][0] for j in single},
        multi=multi,
        k_first=np.array([ks[j][0] for j in multi], dtype=float),
        n_k=np.array([len(ks[j]) for j in multi], dtype=float),
        radix=radix,
        valid=valid,
        n_valid=valid.sum(axis=1).astype(np.int64),
    )


def _branches_chunk(E: F64, Z: F64, keep: NDArray[np.bool_]) -> None:
    r00, r01, r02, px, r10, r11, r12, py, r20, r21, r22, pz = E[:12]
    wx, wy, wz = px - _D6 * r02, py - _D6 * r12, pz - _D6 * r22
    rho = np.sqrt(wx * wx + wy * wy)  # not np.hypot: 10x slower, and no overflow here
    regular = rho > SINGULAR_TOL
    rho_safe = np.where(regular, rho, 1.0)
    c1, s1 = wx / rho_safe, wy / rho_safe
    # Rz(-J1) R of the front shoulder (the back one negates rows 0 and 1): row 0 and R'[1, 2]
    p0, p1, p2 = c1 * r00 + s1 * r10, c1 * r01 + s1 * r11, c1 * r02 + s1 * r12
    q12 = c1 * r12 - s1 * r02
    j1 = np.arctan2(wy, wx)

    # arm, broadcast over (shoulder, elbow, pose)
    sig = _SHOULDER_SIGN
    u = sig * rho - _A1  # (2, 1, N)
    r2 = u * u + wz * wz
    cos_e = (r2 - (_C2 * _C2 + _L * _L)) * (0.5 / (_C2 * _L))
    arm_ok = (np.abs(cos_e) <= 1.0 + 1e-12) & regular
    np.clip(cos_e, -1.0, 1.0, out=cos_e)
    sin_e = _ELBOW_SIGN * np.sqrt(1.0 - cos_e * cos_e)  # (2, 2, N)
    # phi2 = atan2(z, u) - atan2(L sin e, C2 + L cos e) as one angle: (X, Y) = r2 (cos, sin)
    k1, k2 = _C2 + _L * cos_e, _L * sin_e
    X = u * k1 + wz * k2
    Y = wz * k1 - u * k2
    j2 = np.arctan2(X, Y)  # J2 = 90 deg - phi2
    # J3 = phi2 + e - delta, by its cosine and sine
    ced = cos_e * _COS_DELTA + sin_e * _SIN_DELTA
    sed = sin_e * _COS_DELTA - cos_e * _SIN_DELTA
    inv_r2 = 1.0 / np.where(r2 > 0.0, r2, 1.0)
    cphi, sphi = X * inv_r2, Y * inv_r2
    cos3 = cphi * ced - sphi * sed
    sin3 = sphi * ced + cphi * sed
    j3 = np.arctan2(sin3, cos3)

    # wrist: M = Rx(90) R_b3^T R with theta23 = -90 deg - J3; Rx(90) M = Rz Ry Rz
    sp2 = sig * p2
    m02 = cos3 * r22 - sin3 * sp2
    m12 = -sig * q12  # (2, 1, N)
    m22 = cos3 * sp2 + sin3 * r22
    m20 = cos3 * (sig * p0) + sin3 * r20
    m21 = cos3 * (sig * p1) + sin3 * r21
    s5 = np.sqrt(m02 * m02 + m12 * m12)
    ok = arm_ok & (s5 > SINGULAR_TOL)  # (2, 2, N)
    j4 = np.arctan2(-m12, m02)  # J4 = -theta4
    j5 = np.arctan2(s5, m22)  # J5 = -theta5
    j6 = np.arctan2(-m21, -m20)  # J6 = -theta6

    j1_deg = j1 * _DEG
    Z[0, 0] = j1_deg
    Z[0, 1] = j1_deg - np.copysign(180.0, j1_deg)
    np.multiply(j2[..., None, :], _DEG, out=Z[1])
    np.multiply(j3[..., None, :], _DEG, out=Z[2])
    for col, angle in ((3, j4), (5, j6)):
        np.multiply(angle, _DEG, out=Z[col, :, :, 0])
        Z[col, :, :, 1] = Z[col, :, :, 0] - np.copysign(180.0, Z[col, :, :, 0])
    np.multiply(j5, _DEG, out=Z[4, :, :, 0])
    np.negative(Z[4, :, :, 0], out=Z[4, :, :, 1])
    keep[...] = ok[:, :, None, :]


def _turn_ks(limits: robot.JointLimits) -> list[list[int]]:
    """Per joint, the whole turns k that can bring an angle in [-180, 180) inside the limits."""
    return [
        [k for k in (-1, 0, 1) if lo <= 180.0 + 360.0 * k and hi >= -180.0 + 360.0 * k]
        for lo, hi in zip(limits.lower_deg, limits.upper_deg, strict=True)
    ]


def _n_turns(limits: robot.JointLimits) -> int:
    return int(np.prod([len(k) for k in _turn_ks(limits)]))


def turn_shifts(limits: robot.JointLimits) -> list[F64]:
    """Every combination of whole turns (+-360 deg) that can bring a joint angle wrapped to
    [-180, 180) inside the limits (J1 at +-180, J3, J4, J6 of this robot have such
    alternatives); `IKSolutions.branch % len(turn_shifts(limits))` indexes this list."""
    per_joint = [[360.0 * k for k in ks] for ks in _turn_ks(limits)]
    return [np.array(c) for c in itertools.product(*per_joint)]


_turn_shifts = turn_shifts  # the former private name
