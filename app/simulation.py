"""Wiring of the simulated cell: builds it from the cell configuration and collects
calibration and validation sets the way the line would (plan a view with the model, move the
true robot, measure with the sensor, measure the spheres with the tracker)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from app.config import CellConfig
from calib import candidates
from calib.identify import Measurements
from calib.model import SystemModel
from fakes.cell import CellSpec, MeasuringVolume, NotVisible, SimSettings, SimulatedCell

F64 = NDArray[np.float64]


def make_cell(cfg: CellConfig, seed: int | None = None, **overrides: object) -> SimulatedCell:
    """The simulated cell of a configuration; `overrides` replace SimSettings fields."""
    s = cfg.sensor
    volume = MeasuringVolume(
        half_x_mm=s["half_fov_x_mm"],
        half_y_mm=s["half_fov_y_mm"],
        z_min_mm=s["standoff_mm"] - s["half_depth_mm"],
        z_max_mm=s["standoff_mm"] + s["half_depth_mm"],
    )
    spec = CellSpec(
        cfg.T_part_base, cfg.T_flange_sensor, cfg.spheres_part_mm, s["sphere_radius_mm"], volume
    )
    sim = cfg.simulation
    settings = SimSettings(
        seed=int(sim["seed"] if seed is None else seed),
        tracker_noise_mm=float(sim["tracker_noise_mm"]),
        sensor_noise_mm=float(sim["sensor_noise_mm"]),
        compliance=bool(sim["compliance"]),
        thermal=bool(sim["thermal"]),
        temp_c=float(sim["temp_c"]),
    )
    return SimulatedCell(spec, replace(settings, **overrides))  # type: ignore[arg-type]


@dataclass(frozen=True)
class DataSet:
    """Measurements plus the tracker's target centres (part frame) they refer to."""

    measurements: Measurements
    targets: dict[str, F64]
    truth_c_sensor_mm: F64
    truth_p_part_mm: F64


def collect(
    cell: SimulatedCell,
    model: SystemModel,
    x: F64,
    points_part_mm: Mapping[str, F64],
    n_each: int,
    rng: np.random.Generator,
    q_by_target: Mapping[str, F64] | None = None,
) -> DataSet:
    """Measure each point from n_each random views (or the given configurations)."""
    qs, cs, ps, ids, c_true, p_true = [], [], [], [], [], []
    targets = {tid: cell.track_point(p) for tid, p in points_part_mm.items()}
    for tid, p in points_part_mm.items():
        if q_by_target is not None:
            options = np.asarray(q_by_target[tid]).reshape(-1, 6)
        else:
            options = candidates.random_configurations(model, x, p, 3 * n_each, rng).q_deg
        got = 0
        for q in options:
            if got == n_each:
                break
            try:
                c = cell.measure_point(q, p)
            except NotVisible:
                continue
            qs.append(q)
            cs.append(c)
            ps.append(targets[tid])
            ids.append(tid)
            c_true.append(cell.centre_in_sensor(q, p)[0])
            p_true.append(p)
            got += 1
    meas = Measurements(
        np.array(qs).reshape(-1, 6),
        np.array(cs).reshape(-1, 3),
        np.array(ps).reshape(-1, 3),
        tuple(ids),
    )
    return DataSet(meas, targets, np.array(c_true).reshape(-1, 3), np.array(p_true).reshape(-1, 3))


def validation_points(cfg: CellConfig, n: int, rng: np.random.Generator) -> dict[str, F64]:
    """n sphere positions (part frame) spread over the workspace: 900-1900 mm from the J1
    axis, -300..700 mm in height, outside the base plate."""
    x0, x1, y0, y1 = cfg.base_plate_mm
    out: dict[str, F64] = {}
    while len(out) < n:
        r, a, z = rng.uniform(900.0, 1900.0), rng.uniform(-np.pi, np.pi), rng.uniform(-300, 700)
        p_base = np.array([r * np.cos(a), r * np.sin(a), z])
        if x0 <= p_base[0] <= x1 and y0 <= p_base[1] <= y1:
            continue
        out[f"V{len(out) + 1:03d}"] = cfg.T_part_base[:3, :3] @ p_base + cfg.T_part_base[:3, 3]
    return out


def validation_set(
    cell: SimulatedCell,
    cfg: CellConfig,
    model: SystemModel,
    x: F64,
    n: int,
    rng: np.random.Generator,
) -> DataSet:
    """n validation positions each measured from one random configuration that sees it."""
    sets: list[DataSet] = []
    have = 0
    for _ in range(20):
        if have >= n:
            break
        points = validation_points(cfg, 2 * (n - have), rng)
        points = {f"V{have + k + 1:03d}": p for k, p in enumerate(points.values())}
        ds = collect(cell, model, x, points, 1, rng)
        keep = [i for i in range(len(ds.measurements))][: n - have]
        sets.append(_take(ds, keep, have))
        have += len(keep)
    return _concat(sets)


def _take(ds: DataSet, rows: list[int], start: int) -> DataSet:
    m = ds.measurements.subset(np.array(rows, dtype=int))
    rename = {old: f"V{start + k + 1:03d}" for k, old in enumerate(m.targets)}
    meas = Measurements(m.q_deg, m.c_sensor_mm, m.p_part_mm, tuple(rename[t] for t in m.targets))
    targets = {rename[t]: ds.targets[t] for t in m.targets}
    return DataSet(meas, targets, ds.truth_c_sensor_mm[rows], ds.truth_p_part_mm[rows])


def _concat(sets: list[DataSet]) -> DataSet:
    meas = Measurements(
        np.concatenate([s.measurements.q_deg for s in sets]),
        np.concatenate([s.measurements.c_sensor_mm for s in sets]),
        np.concatenate([s.measurements.p_part_mm for s in sets]),
        tuple(t for s in sets for t in s.measurements.targets),
    )
    targets = {k: v for s in sets for k, v in s.targets.items()}
    return DataSet(
        meas,
        targets,
        np.concatenate([s.truth_c_sensor_mm for s in sets]),
        np.concatenate([s.truth_p_part_mm for s in sets]),
    )
