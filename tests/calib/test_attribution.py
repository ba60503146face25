"""Step attribution (calib.attribution): a known step of each kind, a few noisy measurements
after it, the right group chosen and the step recovered; several groups at once refused.

The truth is the model itself: a calibrated state x_true that differs from the parameters in
force x_ref by a small calibration error in every parameter (what the step attribution must not
chase), then a step of one group. The measurements after the step are at configurations whose
pre-step residuals are known (the reference), as the service pairs each post-step measurement
with the last visit of the same slot."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray

from app.config import CellConfig
from calib import candidates
from calib.attribution import (
    NONE,
    SEVERAL,
    attribute,
    point_shift_mm,
    predicted_std_mm,
    step_groups,
)
from calib.errors import InsufficientData
from calib.identify import Measurements, residuals
from calib.model import BASE_NAMES, INDEX, PAPER_30, SENSOR_NAMES, SystemModel
from calib.transforms import apply

F64 = NDArray[np.float64]
#: the model, the spheres in the part frame, the parameters in force, the true cell before the step
World = tuple[SystemModel, dict[str, F64], F64, F64]

NOISE_MM = 0.02  # one coordinate of a measured centre


def _views(model: SystemModel, spheres: dict[str, np.ndarray], n: int, seed: int) -> Measurements:
    """n views spread over the spheres (their centres in the sensor frame come later)."""
    rng = np.random.default_rng([seed, 1])
    x0 = model.nominal_x()
    ids = sorted(spheres)
    qs, ps, tids = [], [], []
    for k in range(n):
        tid = ids[k % len(ids)]
        q = candidates.random_configurations(model, x0, spheres[tid], 1, rng).q_deg[0]
        qs.append(q)
        ps.append(spheres[tid])
        tids.append(tid)
    q_arr = np.array(qs)
    return Measurements(q_arr, np.zeros((n, 3)), np.array(ps), tuple(tids))


def _measure(
    model: SystemModel, x: np.ndarray, views: Measurements, rng: np.random.Generator
) -> Measurements:
    """The sphere centres in the sensor frame the cell `x` gives, plus noise."""
    T = model.fk(x, views.q_deg)
    c = np.array([apply(np.linalg.inv(Ti), p) for Ti, p in zip(T, views.p_part_mm, strict=True)])
    c = c + rng.normal(0.0, NOISE_MM, c.shape)
    return Measurements(views.q_deg, c, views.p_part_mm, views.targets)


def _step(kind: str, rng: np.random.Generator) -> tuple[list[str], np.ndarray]:
    """The parameters a knock of `kind` moves and by how much (the issue's sizes)."""
    if kind == "sensor":  # 0.3 mm, 0.05 deg
        t, r = rng.normal(size=3), rng.normal(size=3)
        return list(SENSOR_NAMES), np.r_[
            0.3 * t / np.linalg.norm(t), np.radians(0.05) * r / np.linalg.norm(r)
        ]
    if kind == "fixture":  # 0.5 mm, 0.03 deg
        t, r = rng.normal(size=3), rng.normal(size=3)
        return list(BASE_NAMES), np.r_[
            0.5 * t / np.linalg.norm(t), np.radians(0.03) * r / np.linalg.norm(r)
        ]
    return ["dtheta2"], np.array([np.radians(0.01)])  # a J2 zero slip


@pytest.fixture(scope="module")
def world(cfg: CellConfig) -> World:
    model = cfg.model()
    rng = np.random.default_rng(7)
    x_ref = model.nominal_x()
    x_ref[[INDEX[n] for n in PAPER_30]] += rng.normal(0.0, 0.05, 30) * np.where(
        [n[0] in "xyzad" and not n.startswith(("alpha", "dtheta")) for n in PAPER_30], 1.0, 1e-4
    )
    # the cell before the step: in force plus a calibration error (0.02 mm, 1e-5 rad per
    # parameter: residuals of about 0.06 mm at the spheres, the service's pre-knock level)
    x_true = x_ref.copy()
    x_true[[INDEX[n] for n in PAPER_30]] += rng.normal(0.0, 0.02, 30) * np.where(
        [n[0] in "xyzad" and not n.startswith(("alpha", "dtheta")) for n in PAPER_30], 1.0, 5e-4
    )
    return model, cfg.spheres_part_mm, x_ref, x_true


def _knocked(
    world: World, kind: str, n: int, seed: int
) -> tuple[SystemModel, F64, F64, F64, Measurements, F64]:
    model, spheres, x_ref, x_true = world
    rng = np.random.default_rng([seed, 2])
    views = _views(model, spheres, n, seed)
    before = _measure(model, x_true, views, rng)
    names, delta = _step(kind, rng)
    x_after = x_true.copy()
    x_after[[INDEX[p] for p in names]] += delta
    after = _measure(model, x_after, views, rng)
    reference = residuals(model, x_ref, before)
    return model, x_ref, x_true, x_after, after, reference


@pytest.mark.parametrize(
    "kind,group", [("sensor", "sensor"), ("fixture", "fixture"), ("joint", "J2")]
)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_known_step_is_attributed_to_its_group_from_five_measurements(
    world: World, kind: str, group: str, seed: int
) -> None:
    model, x_ref, x_true, x_after, after, reference = _knocked(world, kind, 5, seed)
    sigma = NOISE_MM * np.sqrt(2.0)  # a difference of two measurements
    a = attribute(model, x_ref, after, sigma_mm=sigma, reference_mm=reference)
    assert a.choice == group, a.text()
    assert a.margin > 10.0  # decisive on the BIC scale (2 ln K > 10: very strong)
    fit = a.chosen
    assert fit is not None and fit.consistent
    # the step is recovered: x_ref moved by the step predicts the knocked cell as x_ref did the
    # cell before (the calibration error stays what it was, the step is gone)
    q, c = after.q_deg, np.tile([0.0, 0.0, 130.0], (len(after), 1))
    step_true = point_shift_mm(model, x_true, x_after, q, c)
    step_left = point_shift_mm(model, x_ref + (x_after - x_true), fit.x, q, c)
    assert step_true > 0.1
    assert step_left < 0.25 * step_true
    # within its own predicted uncertainty (4 sigma: 9 cases; measured z RMS 1.0-1.2 over 30)
    assert step_left < 4.0 * predicted_std_mm(model, fit, q, c) + 0.01
    assert group in a.text() or fit.group.label in a.text()
    assert f"{len(after)} measurements" in a.text()


def test_the_sensor_step_size_is_reported_in_mm_and_deg(world: World) -> None:
    model, x_ref, _, _, after, reference = _knocked(world, "sensor", 8, 3)
    a = attribute(model, x_ref, after, sigma_mm=NOISE_MM * np.sqrt(2.0), reference_mm=reference)
    fit = a.chosen
    assert a.choice == "sensor" and fit is not None
    # the knock moved the sensor's origin 0.3 mm and tilted it 0.05 deg: centres near one
    # point of the field of view confound the two (each within a few of its own sigma), their
    # effect on the measured centres is well determined
    _, _, x_true, x_after, _, _ = _knocked(world, "sensor", 8, 3)
    true_shift = point_shift_mm(model, x_true, x_after, after.q_deg, after.c_sensor_mm)
    assert fit.shift_mm == pytest.approx(true_shift, rel=0.15)
    z = (fit.step - (x_after - x_true)[[INDEX[p] for p in SENSOR_NAMES]]) / fit.std
    assert np.all(np.abs(z) < 4.0)
    assert "sensor mount moved" in a.text() and " deg" in a.text() and "at the measured" in a.text()
    doc = a.to_json()
    assert doc["choice"] == "sensor" and a.fits[0].group.name == "sensor"
    assert doc["text"] == a.text() and isinstance(doc["fits"], list)


def test_two_groups_moved_at_once_is_several(world: World) -> None:
    model, spheres, x_ref, x_true = world
    rng = np.random.default_rng(5)
    views = _views(model, spheres, 8, 5)
    before = _measure(model, x_true, views, rng)
    x_after = x_true.copy()
    for kind in ("sensor", "fixture"):
        names, delta = _step(kind, rng)
        x_after[[INDEX[p] for p in names]] += 2.0 * delta
    after = _measure(model, x_after, views, rng)
    a = attribute(
        model,
        x_ref,
        after,
        sigma_mm=NOISE_MM * np.sqrt(2.0),
        reference_mm=residuals(model, x_ref, before),
    )
    assert a.choice == SEVERAL
    assert "several groups moved" in a.text() and "waiting for the full recalibration" in a.text()


def test_too_few_equations_leave_a_group_undetermined(world: World) -> None:
    model, x_ref, _, _, after, reference = _knocked(world, "joint", 1, 6)
    a = attribute(model, x_ref, after, sigma_mm=0.03, reference_mm=reference[:1])
    sensor = a.fit("sensor")
    assert not sensor.determined and not np.isfinite(sensor.bic)
    assert a.fit(SEVERAL).determined is False
    assert a.choice != "sensor"  # only nothing and the joints are determined
    assert [f.group.name for f in a.fits][-1] in ("sensor", "fixture", SEVERAL)


def test_no_step_is_none(world: World) -> None:
    """A false alarm: the same cell measured again, nothing moved."""
    model, spheres, x_ref, x_true = world
    rng = np.random.default_rng(9)
    views = _views(model, spheres, 6, 9)
    before, again = _measure(model, x_true, views, rng), _measure(model, x_true, views, rng)
    a = attribute(
        model,
        x_ref,
        again,
        sigma_mm=NOISE_MM * np.sqrt(2.0),
        reference_mm=residuals(model, x_ref, before),
    )
    assert a.choice == NONE and a.chosen is not None and a.chosen.consistent
    assert a.text().startswith("no step found")


def test_groups_of_the_model(cfg: CellConfig) -> None:
    names = [g.name for g in step_groups(cfg.model())]
    assert names == [NONE, "sensor", "fixture", "J2", "J3", "J4", "J5", SEVERAL]
    assert step_groups(cfg.model())[-1].params == PAPER_30


def test_bad_input_is_refused(world: World) -> None:
    model, x_ref, _, _, after, reference = _knocked(world, "joint", 3, 8)
    with pytest.raises(InsufficientData):
        attribute(model, x_ref, after.subset(np.arange(0)), sigma_mm=0.03)
    with pytest.raises(InsufficientData):
        attribute(model, x_ref, after, sigma_mm=0.0)
    with pytest.raises(InsufficientData):
        attribute(model, x_ref, after, sigma_mm=0.03, reference_mm=reference[:2])
