"""Benchmark of the closed-form IK (calib.ik.solve) against the public `py-opw-kinematics`
package (Rust core, a development dependency) on the same random reachable flange poses, in
the same run. Prints medians of repeated, interleaved runs, poses per second and the ratio,
and the solutions per pose of each.

    .venv/bin/python bench/ik.py

Conventions (REFERENCE.md): py-opw-kinematics works in the URDF `base_link` frame (565 mm below
FANUC World) with URDF joint angles (q3 = J2 + J3); its OPW parameters are a1 = 150, a2 = -170,
b = 0, c1 = 565, c2 = 870, c3 = 1016, c4 = 175, offsets (0, 0, -90, 0, 0, 180) deg, sign
corrections (1, 1, -1, -1, -1, -1). Its `reach` returns all eight branches of every pose
(no limits, no turn alternatives, plus margins and the smallest singular value of the
Jacobian); `inverse` returns the valid solutions of one pose; `batch_inverse` one solution per
pose. Our `solve` returns every branch within the controller limits, with or without the
whole-turn (+-360 deg) alternatives of J1/J3/J4/J6.
"""

from __future__ import annotations

from app.threads import limit_blas_threads

limit_blas_threads()  # as the rvis entry point, before numpy loads

import statistics
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from calib import ik, robot
from calib.model import SystemModel

F64 = np.ndarray

OPW_PARAMETERS: dict[str, Any] = dict(
    a1=150.0, a2=-170.0, b=0.0, c1=565.0, c2=870.0, c3=1016.0, c4=175.0,
    offsets=(0.0, 0.0, -90.0, 0.0, 0.0, 180.0),
    flip_axes=(False, False, True, True, True, True),
)  # fmt: skip


def opw_robot() -> Any | None:
    """The py-opw-kinematics robot of the M-710iC/50 (degrees), or None if not installed."""
    try:
        from py_opw_kinematics._internal import KinematicModel, Robot
    except ImportError:
        return None
    return Robot(KinematicModel(**OPW_PARAMETERS), True)


def random_reachable_poses(n: int, seed: int = 0) -> F64:
    """Flange poses T_world_flange (n, 4, 4) [mm] of random controller angles within the
    limits (so every pose has at least one solution)."""
    lim = robot.JointLimits()
    q_deg = np.random.default_rng(seed).uniform(lim.lower_deg, lim.upper_deg, (n, 6))
    model = SystemModel(np.eye(4), np.eye(4))
    return model.fk(model.nominal_x(), q_deg, flange=True)


def to_opw_poses(T_world_flange: F64) -> F64:
    """World -> base_link (565 mm lower), flattened (n, 16) as py-opw-kinematics wants."""
    T = np.array(T_world_flange, dtype=float).reshape(-1, 4, 4)
    T[:, 2, 3] += robot.BASE_LINK_TO_WORLD_Z_MM
    return np.ascontiguousarray(T.reshape(-1, 16))


def opw_to_controller_deg(q_urdf_deg: F64) -> F64:
    """URDF joint angles (..., 6) -> controller angles (J3 = q3 - J2), wrapped to [-180, 180)."""
    q = np.array(q_urdf_deg, dtype=float)
    q[..., 2] -= q[..., 1]
    wrapped: F64 = (q + 180.0) % 360.0 - 180.0
    return wrapped


def opw_solutions_within_limits(rob: Any, T_world_flange: F64) -> list[F64]:
    """py-opw-kinematics's branches of each pose, as controller angles within our limits
    (no turn alternatives: comparable to `ik.solve(..., turn_alternatives=False)`)."""
    joints = rob.reach(to_opw_poses(T_world_flange), None, None, 1)[0]
    lim = robot.JointLimits()
    out = []
    for q in joints:
        q = opw_to_controller_deg(q[np.all(np.isfinite(q), axis=1)])
        out.append(q[lim.contains(q)])
    return out


@dataclass(frozen=True)
class Row:
    name: str
    seconds: float  # median wall clock
    cpu_seconds: float  # median process CPU time (all threads)
    n_poses: int
    solutions_per_pose: float

    @property
    def poses_per_s(self) -> float:
        return self.n_poses / self.seconds


def interleaved_medians(
    fns: dict[str, Callable[[], object]], repeats: int
) -> dict[str, tuple[float, float]]:
    """Median wall-clock and CPU seconds of each function, run in rotation (a shared load
    hits all alike)."""
    for fn in fns.values():
        fn()  # warm-up
    times: dict[str, list[tuple[float, float]]] = {k: [] for k in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            t, c = time.perf_counter(), time.process_time()
            fn()
            times[name].append((time.perf_counter() - t, time.process_time() - c))
    return {
        k: (statistics.median(w for w, _ in v), statistics.median(c for _, c in v))
        for k, v in times.items()
    }


def run(n: int, repeats: int = 11, seed: int = 0, with_loop: bool = True) -> list[Row]:
    """Our solve (with and without turn alternatives) and py-opw-kinematics's batch APIs on
    the same n poses; py-opw rows are missing when the package is not installed."""
    T = random_reachable_poses(n, seed)
    rob = opw_robot()
    fns: dict[str, Callable[[], object]] = {
        "ours: solve, turn alternatives": lambda: ik.solve(T),
        "ours: solve, no turn alternatives": lambda: ik.solve(T, turn_alternatives=False),
    }
    per_pose = {
        "ours: solve, turn alternatives": len(ik.solve(T).q_deg) / n,
        "ours: solve, no turn alternatives": len(ik.solve(T, turn_alternatives=False).q_deg) / n,
    }
    if rob is not None:
        flat = to_opw_poses(T)
        joints = rob.reach(flat, None, None, 1)[0]
        n_all = float(np.all(np.isfinite(joints), axis=2).sum()) / n
        n_lim = sum(len(q) for q in opw_solutions_within_limits(rob, T)) / n
        fns["py-opw: reach, 1 thread (8 branches)"] = lambda: rob.reach(flat, None, None, 1)
        fns["py-opw: reach, all cores (8 branches)"] = lambda: rob.reach(flat, None, None, 0)
        fns["py-opw: batch_inverse (1 per pose)"] = lambda: rob.batch_inverse(flat, None, None)
        per_pose["py-opw: reach, 1 thread (8 branches)"] = n_all
        per_pose["py-opw: reach, all cores (8 branches)"] = n_all
        per_pose["py-opw: batch_inverse (1 per pose)"] = 1.0
        if with_loop:
            T_opw = flat.reshape(-1, 4, 4)
            name = "py-opw: inverse, per-pose loop"
            fns[name] = lambda: [rob.inverse(t) for t in T_opw]
            per_pose[name] = sum(len(rob.inverse(t)) for t in T_opw[:2000]) / min(n, 2000)
        per_pose["(py-opw branches within our limits)"] = n_lim
    med = interleaved_medians(fns, repeats)
    rows = [Row(k, med[k][0], med[k][1], n, per_pose[k]) for k in fns]
    if rob is not None:
        nan = float("nan")
        rows.append(Row("(py-opw branches within our limits)", nan, nan, n, n_lim))
    return rows


def speedups(rows: list[Row]) -> dict[str, float]:
    """Our throughput over py-opw's `reach` (1 thread and its best of all APIs that return
    every branch), with and without turn alternatives."""
    by = {r.name: r for r in rows}
    out: dict[str, float] = {}
    opw_all = [r for r in rows if r.name.startswith("py-opw") and "1 per pose" not in r.name]
    if not opw_all:
        return out
    best = min(opw_all, key=lambda r: r.seconds)
    ref = by["py-opw: reach, 1 thread (8 branches)"]
    for mine in ("ours: solve, turn alternatives", "ours: solve, no turn alternatives"):
        out[f"{mine} vs py-opw reach 1 thread"] = ref.seconds / by[mine].seconds
        out[f"{mine} vs py-opw reach 1 thread, CPU time"] = ref.cpu_seconds / by[mine].cpu_seconds
        out[f"{mine} vs fastest py-opw all-branch ({best.name[8:]})"] = (
            best.seconds / by[mine].seconds
        )
    return out


def agreement(n: int = 1000, seed: int = 1) -> tuple[float, int]:
    """Max FK error [mm or rad-ish entries] of our solutions, and the number of poses whose
    solution set (no turns, within limits) differs from py-opw-kinematics's (-1: missing)."""
    T = random_reachable_poses(n, seed)
    sols = ik.solve(T, turn_alternatives=False)
    model = SystemModel(np.eye(4), np.eye(4))
    T_fk = model.fk(model.nominal_x(), sols.q_deg, flange=True)
    err = float(np.abs(T_fk - T[sols.pose_index]).max())
    rob = opw_robot()
    if rob is None:
        return err, -1
    theirs = opw_solutions_within_limits(rob, T)
    differ = 0
    for i in range(n):
        a, b = sols.for_pose(i), theirs[i]
        if len(a) != len(b):
            differ += 1
            continue
        d = np.abs(((a[:, None, :] - b[None, :, :]) + 180.0) % 360.0 - 180.0).max(axis=2)
        differ += int(len(a) > 0 and d.min(axis=1).max() > 1e-6)
    return err, differ


def print_table(rows: list[Row]) -> None:
    print(
        f"{'what':40s} {'poses':>7s} {'median':>10s} {'poses/s':>11s} {'cpu':>10s} {'sol/pose':>8s}"
    )
    for r in rows:
        if np.isnan(r.seconds):
            print(f"{r.name:40s} {r.n_poses:7d} {'':>34s} {r.solutions_per_pose:8.2f}")
            continue
        print(
            f"{r.name:40s} {r.n_poses:7d} {r.seconds * 1e3:7.1f} ms {r.poses_per_s:11,.0f} "
            f"{r.cpu_seconds * 1e3:7.1f} ms {r.solutions_per_pose:8.2f}"
        )
    for k, v in speedups(rows).items():
        print(f"  {k}: {v:.1f}x (aim >= 3x)")


def refine_timing(n: int = 1000, repeats: int = 11) -> tuple[float, float, float]:
    """Median seconds of `ik_refine.solve_on_model` on n sensor poses of a model ~0.5 mm /
    1 mrad off nominal, the share of its solutions converged, and its solutions per pose."""
    from calib import ik_refine
    from calib.model import INDEX, PAPER_30, unit_of
    from calib.transforms import pose, rotvec_to_matrix

    model = SystemModel(
        pose(rotvec_to_matrix([0.01, -0.02, 0.3]), [2000.0, -300.0, 100.0]),
        pose(rotvec_to_matrix([0.0, 0.0, 0.5]), [10.0, 20.0, 150.0]),
    )
    rng = np.random.default_rng(0)
    x = model.nominal_x()
    for name in PAPER_30:
        x[INDEX[name]] += rng.normal() * (0.5 if unit_of(name) == "mm" else 1e-3)
    lim = robot.JointLimits()
    T = model.fk(x, rng.uniform(lim.lower_deg, lim.upper_deg, (n, 6)))
    med = interleaved_medians({"r": lambda: ik_refine.solve_on_model(model, x, T)}, repeats)
    sols = ik_refine.solve_on_model(model, x, T)
    return med["r"][0], float(sols.converged.mean()), len(sols.q_deg) / n


def main() -> None:
    print(
        "median of interleaved runs; wall clock is the figure, cpu the process CPU time (the\n"
        "machine may be shared: cpu shows the work, wall what a caller waits)"
    )
    if opw_robot() is None:
        print("py-opw-kinematics is not installed: only our timings")
    err, differ = agreement()
    print(f"FK(IK(T)) max |error| over 1000 poses: {err:.1e}; poses whose branch set differs "
          f"from py-opw-kinematics: {differ}")  # fmt: skip
    for n, repeats in ((10_000, 21), (100_000, 5)):
        print()
        print_table(run(n, repeats, with_loop=n <= 10_000))
    t, conv, per_pose = refine_timing()
    print(
        f"\nIK on the identified model (closed form + <= 5 Gauss-Newton steps), 1000 poses: "
        f"{t * 1e3:.1f} ms, {per_pose:.1f} solutions/pose, {conv:.1%} converged"
    )


if __name__ == "__main__":
    main()
