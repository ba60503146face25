"""A version identified on one group with the rest held (a maintenance procedure's): its
covariance keeps the held parameters' block from the version before and the group's own, so
the per-point U95 (app.api.Calibration.u95_mm) counts every parameter's uncertainty."""

from __future__ import annotations

from typing import Any

import numpy as np

from app.formats.params import document_covariance, with_held_covariance


def _doc(names: list[str], cov: np.ndarray, all_names: list[str]) -> dict[str, Any]:
    std = np.sqrt(np.diag(cov))
    return {
        "active": names,
        "correlation": (cov / np.outer(std, std)).tolist(),
        "parameters": [
            {"name": n, "std": float(std[names.index(n)]) if n in names else 0.0} for n in all_names
        ],
    }


def test_the_held_block_comes_from_before_the_group_from_the_new_fit() -> None:
    names = ["a", "b", "c", "d"]
    rng = np.random.default_rng(3)
    m = rng.normal(size=(4, 4))
    before = _doc(names, m @ m.T + np.eye(4), names)
    group = np.array([[0.04, 0.01], [0.01, 0.09]])
    doc = _doc(["c", "d"], group, names)
    with_held_covariance(doc, before, "params-before.json")
    got = document_covariance(doc, "x.json")
    assert got is not None
    got_names, cov = got
    assert set(got_names) == set(names)
    idx = {n: k for k, n in enumerate(got_names)}
    old = document_covariance(before, "b.json")
    assert old is not None
    for i in ("a", "b"):
        for j in ("a", "b"):
            assert np.isclose(cov[idx[i], idx[j]], old[1][names.index(i), names.index(j)])
    assert np.allclose(cov[np.ix_([idx["c"], idx["d"]], [idx["c"], idx["d"]])], group)
    assert cov[idx["a"], idx["c"]] == 0.0
    stds = {p["name"]: p["std"] for p in doc["parameters"]}
    assert np.isclose(stds["a"], np.sqrt(old[1][0, 0])) and np.isclose(stds["c"], 0.2)


def test_nothing_changes_without_a_covariance_before() -> None:
    doc = _doc(["c"], np.array([[0.04]]), ["a", "c"])
    with_held_covariance(doc, {"parameters": []}, "params-before.json")
    assert doc["active"] == ["c"]
