"""The body's rendered path (fakes/render_sheet.py, then vision's stripe extraction,
triangulation and feature fits: app.sim.bodies.rendered_profiles): a hole, a slot and a surface
point rendered by the true sensor at an oblique view and measured with the true sensor's model,
against the geometry they were rendered from. The bore's wall is seen through the opening (the
stripe bends into it below the top face), and the edge is still the top face's."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from numpy.typing import NDArray

from app.line.measure import SweepFeatureSensor
from app.sim.bodies import rendered_profiles
from app.sim.cell import true_sensor_model
from drivers.camera import Frame
from fakes.render_sensor import TrueSensor
from fakes.render_sheet import (
    bench_commands,
    bench_pose,
    feature_surface,
    render_feature_sweep,
)
from vision.features import measure_feature

F64 = NDArray[np.float64]
THICKNESS_MM = 1.2


@pytest.mark.parametrize(
    ("kind", "size", "tol_centre", "tol_size"),
    # one sweep's scatter (the camera's rows sample the edge every 28 um, the speckle decides
    # the last lit one; tests/sim/test_render_edge.py): a diameter within 13 um, a slot's
    # length within 30 um, a centre within 15-20 um
    [("hole", (12.0,), 0.015, 0.013), ("slot", (8.0, 20.0), 0.02, 0.03), ("surface", (), 0.005, 0)],
)
def test_a_rendered_feature_is_measured_where_it_was_rendered(
    true_sensor: TrueSensor, kind: str, size: tuple[float, ...], tol_centre: float, tol_size: float
) -> None:
    T = bench_pose(12.0)
    R, t = T[:3, :3], T[:3, 3]
    half = 0.5 * max(size, default=8.0) + 3.0
    cmds = bench_commands(true_sensor, half, 40 if size else 12)
    profiles = rendered_profiles(
        T, kind, size, THICKNESS_MM, true_sensor, true_sensor_model(true_sensor),
        np.random.default_rng(5), cmds,
    )  # fmt: skip
    fit = measure_feature(kind, profiles, t, R[:, 2], size, R[:, 0])  # in the sensor frame
    assert np.linalg.norm(R.T @ (fit.centre_mm - t)) < tol_centre
    for got, want in zip(fit.size_mm, size, strict=True):
        assert abs(got - want) < tol_size
    if kind != "surface":
        assert fit.coverage >= 0.6 and fit.n_edge_points >= 30


def test_the_wall_is_seen_through_the_opening_and_nothing_behind_it(
    true_sensor: TrueSensor,
) -> None:
    flat, X, _ = feature_surface(bench_pose(12.0), "hole", (12.0,), THICKNESS_MM, true_sensor)
    T = bench_pose(12.0)
    Xf = (X - T[:3, 3]) @ T[:3, :3]
    r = np.hypot(Xf[:, 0], Xf[:, 1])
    top = np.abs(Xf[:, 2]) < 1e-9
    assert np.all(r[top] >= 6.0 - 1e-9)  # no top face inside the hole
    wall = ~top
    assert wall.any() and np.allclose(r[wall], 6.0, atol=1e-4)
    assert np.all((Xf[wall, 2] <= 0) & (Xf[wall, 2] >= -THICKNESS_MM - 1e-6))
    assert len(np.unique(flat)) == len(flat)  # one surface point a pixel


class _RenderedCell:
    """The camera and galvo of a real cell as app.line.measure.SweepFeatureSensor drives them,
    in front of the rendered sweep of one feature: the galvo's command picks the frame the
    true sensor recorded at it."""

    def __init__(self, commands_v: F64, frames: NDArray[np.generic]) -> None:
        self.frames = dict(zip(np.round(commands_v, 9).tolist(), frames, strict=True))
        self.volts = 0.0

    def set_volts(self, volts: float) -> None:
        self.volts = volts

    def grab(self, timeout_s: float) -> Frame:
        image = self.frames[round(self.volts, 9)]
        return Frame(image, len(self.frames), 0, 100.0, 0.0)


def test_a_real_cells_feature_sweep_puts_the_edge_by_the_light(true_sensor: TrueSensor) -> None:
    """The real sensor's sweep (`SweepFeatureSensor`, what `rvis run` measures bodies with)
    gives each point its light, as the simulated line's rendered path does: a slot's width
    and length within one sweep's scatter of the geometry rendered, the galvo parked after."""
    T = bench_pose(10.0)
    R, t = T[:3, :3], T[:3, 3]
    size = (8.0, 20.0)
    cmds = bench_commands(true_sensor, 0.5 * max(size) + 3.0, 40)
    frames = render_feature_sweep(
        T, "slot", size, THICKNESS_MM, true_sensor, np.random.default_rng(5), cmds
    )
    cell = _RenderedCell(cmds, frames)
    sensor = SweepFeatureSensor(cell, cell, true_sensor_model(true_sensor))  # type: ignore[arg-type]
    profiles = sensor.profiles(SimpleNamespace(commands_v=cmds))
    assert cell.volts == 0.0 and all(p.shape[1] == 7 for p in profiles if len(p))
    fit = measure_feature("slot", profiles, t, R[:, 2], size, R[:, 0])
    assert np.linalg.norm(R.T @ (fit.centre_mm - t)) < 0.02
    assert abs(fit.size_mm[0] - size[0]) < 0.013 and abs(fit.size_mm[1] - size[1]) < 0.03


def test_rvis_run_on_a_real_cell_measures_the_state_directorys_part_type(tmp_path: Path) -> None:
    """`rvis run` on devices (app.commands.run): with a feature plan in the state directory
    its bodies are measured with the sensor's sweeps; without one none is."""
    from app.config import load_cell
    from app.line.body_cycle import sweep_bodies
    from app.sim.part import ensure_features
    from vision.sensor_model import default_sensor_model

    cfg, model = load_cell(None), default_sensor_model()
    assert sweep_bodies(tmp_path, cfg.T_part_base, None, None, model) is None
    ensure_features(tmp_path, cfg)
    setup = sweep_bodies(tmp_path, cfg.T_part_base, "camera", "galvo", model)
    assert setup is not None and len(setup.plan.features) >= 20
    assert isinstance(setup.sensor, SweepFeatureSensor)
    assert (setup.sensor.camera, setup.sensor.galvo) == ("camera", "galvo")
