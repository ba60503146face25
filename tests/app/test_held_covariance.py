"""A version identified on one group with the rest held (a maintenance procedure's): its
covariance keeps the held parameters' block from the version before, and the group's carries
what their uncertainty moves it by (with the covariance between them), so the per-point U95
(app.api.Calibration.u95_mm) counts every parameter's uncertainty (issue 51 item 4)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.api import Calibration
from app.config import load_cell
from app.formats.files import write_json
from app.formats.params import covariance_of, document_covariance, to_json, with_held_covariance
from app.maintain.reidentify import group_document
from calib.identify import Measurements, identify
from calib.model import BASE_NAMES, INDEX, SENSOR_NAMES
from calib.uncertainty import norm_quantile
from tests.conftest import simulated


def _doc(names: list[str], cov: np.ndarray, all_names: list[str]) -> dict[str, Any]:
    std = np.sqrt(np.diag(cov))
    return {
        "active": names,
        "correlation": (cov / np.outer(std, std)).tolist(),
        "parameters": [
            {"name": n, "std": float(std[names.index(n)]) if n in names else 0.0} for n in all_names
        ],
    }


def test_the_held_block_comes_from_before_the_group_carries_it() -> None:
    """On a small linear model: the held block is the version before's, the group's its fit's
    own plus G C_aa G^T, between them G C_aa (G = d group / d held, in `gain`)."""
    names = ["a", "b", "c", "d"]
    rng = np.random.default_rng(3)
    m = rng.normal(size=(4, 4))
    before = _doc(names, m @ m.T + np.eye(4), names)
    group = np.array([[0.04, 0.01], [0.01, 0.09]])
    doc = _doc(["c", "d"], group, names)
    G = np.array([[0.5, -0.2], [0.1, 0.3]])  # d(c, d) / d(a, b)
    asked: list[list[str]] = []

    def gain(held: list[str]) -> np.ndarray:
        asked.append(held)
        return G

    with_held_covariance(doc, before, "params-before.json", gain)
    assert asked == [["a", "b"]]
    got = document_covariance(doc, "x.json")
    assert got is not None
    got_names, cov = got
    assert set(got_names) == set(names)
    idx = [got_names.index(n) for n in names]
    cov = cov[np.ix_(idx, idx)]
    old = document_covariance(before, "b.json")
    assert old is not None
    c_aa = old[1][:2, :2]
    assert np.allclose(cov[:2, :2], c_aa, rtol=1e-5)
    assert np.allclose(cov[2:, 2:], group + G @ c_aa @ G.T, rtol=1e-5)
    assert np.allclose(cov[2:, :2], G @ c_aa, rtol=1e-5, atol=1e-9)
    stds = {p["name"]: p["std"] for p in doc["parameters"]}
    assert np.isclose(stds["a"], np.sqrt(c_aa[0, 0]))
    assert np.isclose(stds["c"], np.sqrt((group + G @ c_aa @ G.T)[0, 0]))
    # no gain (the held values move the group not at all): the fit's own, nothing between
    doc = _doc(["c", "d"], group, names)
    with_held_covariance(doc, before, "params-before.json", lambda held: np.zeros((2, 2)))
    got = document_covariance(doc, "x.json")
    assert got is not None
    k = [got[0].index(n) for n in ("c", "d")]
    assert np.allclose(got[1][np.ix_(k, k)], group) and got[1][got[0].index("a"), k[0]] == 0.0


def test_nothing_changes_without_a_covariance_before() -> None:
    doc = _doc(["c"], np.array([[0.04]]), ["a", "c"])

    def never(held: list[str]) -> np.ndarray:
        raise AssertionError("asked for a gain without a covariance before")

    with_held_covariance(doc, {"parameters": []}, "params-before.json", never)
    assert doc["active"] == ["c"]


#: draws of the Monte Carlo (a std to +-2.5 %, 1 sigma)
DRAWS = 800


@pytest.mark.parametrize("group", [SENSOR_NAMES, BASE_NAMES], ids=["sensor", "fixture"])
def test_the_refitted_group_carries_the_held_parameters_uncertainty(
    tmp_path: Path, group: tuple[str, ...]
) -> None:
    """A procedure refits one group with the rest held at the version before, whose values are
    uncertain (its covariance): the group's estimate follows them (b = f(data, a)), so its
    covariance is the fit's own plus G C_aa G^T (G = d b / d a), with C_ba = G C_aa. Checked
    against the Monte Carlo of the procedure on the simulated cell: the held values drawn from
    the version before's covariance, the measurements' noise at its fit's sigma, the group
    refitted each time. Was (issue 51 item 4): the group's std its fit's alone (z_FS 0.60x,
    rz_PB 0.51x the spread) and the per-point U95 down to 0.82x the true one at some points
    (1.26x at others: the cross-covariance left out); now 1.02-1.15x and 0.97-1.08x."""
    cfg = load_cell(None)
    model = cfg.model()
    cal, val = simulated(0, 80)
    first = identify(model, cal.measurements)  # the version before: the 30 from 24 views
    before = tmp_path / "params-before.json"
    write_json(before, to_json(model, first))
    got = covariance_of(before)
    assert got is not None
    names, cov = got
    held = [n for n in names if n not in group]
    ih = [names.index(n) for n in held]
    chol = np.linalg.cholesky(cov[np.ix_(ih, ih)])
    x_true = first.x  # the cell now: the held parameters as before, the group too
    views = val.measurements.subset(np.arange(24))  # the procedure's
    exact = model.points_part(x_true, views.q_deg, views.c_sensor_mm)
    at = val.measurements.subset(np.arange(40, 80))  # points measured after it
    p_true = model.points_part(x_true, at.q_deg, at.c_sensor_mm)
    cols, held_cols = [INDEX[n] for n in group], [INDEX[n] for n in held]
    rng = np.random.default_rng(5)

    def procedure() -> tuple[Any, Measurements]:
        x0 = x_true.copy()
        x0[held_cols] += chol @ rng.normal(size=len(held))
        noisy = exact + rng.normal(scale=first.sigma_mm, size=exact.shape)
        data = Measurements(views.q_deg, views.c_sensor_mm, noisy, views.targets)
        return identify(model, data, active=group, x0=x0, align=False), data

    fits = [procedure()[0] for _ in range(DRAWS)]
    spread = np.std([f.x[cols] for f in fits], axis=0)
    errors = np.array([model.points_part(f.x, at.q_deg, at.c_sensor_mm) - p_true for f in fits])
    # the per-point U95 of the spread as app.api.Calibration.u95_mm states one (its largest
    # per-coordinate variance, at norm_quantile's factor)
    k = norm_quantile()
    u95_true = np.array(
        [k * np.sqrt(np.linalg.eigvalsh(np.cov(e.T))[-1]) for e in errors.swapaxes(0, 1)]
    )
    # the procedure's document of one of them
    fit, data = procedure()
    doc = group_document(model, data, fit, None, before)
    stated = document_covariance(doc, "params.json")
    assert stated is not None and set(stated[0]) == set(names)
    std = np.sqrt(np.diag(stated[1]))[[stated[0].index(n) for n in group]]
    u95 = Calibration(model, fit.x, "", stated).u95_mm(at.q_deg, at.c_sensor_mm)
    ratio, point = std / spread, u95 / u95_true
    print(f"{group[0][-2:]}: std / spread {np.round(ratio, 2)}, per-point U95 / true "
          f"{point.min():.2f}..{point.max():.2f}")  # fmt: skip
    assert np.all(ratio >= 0.9), dict(zip(group, ratio.round(2), strict=True))
    assert np.all(point >= 0.9), point.round(2)
    # and not grossly more (its fit's sigma counts the held parameters' misfit as noise too)
    assert np.all(ratio <= 1.35) and np.all(point <= 1.35), (ratio.round(2), point.round(2))
