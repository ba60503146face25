"""The body measured in the cycle, end to end (issue 48 items 4-6): a commissioned simulated
cell with the part type's feature plan, the service on the simulated line measuring every
clamped body's features while the PLC holds body_ready, storing each body's values with their
raw data before it tells the PLC body_done (and body_nok), and, after a sensor knock is found
and corrected, computing the bodies measured inside its suspect interval again with the
correction, beside the values as measured. Judged against the simulated bodies' truth (what a
CMM reports). Seed 7, named before the test was run."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from app.api import Calibration
from app.config import load_cell
from app.inspect.measure import evaluate_body
from app.inspect.values import StopNoise
from app.line.body_cycle import raw_of
from app.line.body_export import file_name
from app.line.launch import hold_state
from app.line.statedir import StateDir
from app.line.store import Store
from app.sim.bodies import true_value
from app.sim.commissioned import commission_simulated
from app.sim.line_run import SimulatedLineRun
from app.sim.part import ensure_features, nominal_features
from fakes.body import BodyShop, BuildProcess

SEED = 7
PERIOD_S, WINDOW_S = 90.0, 40.0  # a body phase of 48 s, a sphere window
KNOCK_AT_S = 5 * PERIOD_S + 20.0  # while the 6th body is measured
WINDOWS = 14


@pytest.fixture(scope="module")
def line_run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    root = tmp_path_factory.mktemp("body")
    state = StateDir(root / "state")
    commission_simulated(load_cell(None), state, SEED)
    cfg = load_cell(state.cell)
    ensure_features(state.root, cfg)
    cfg = dataclasses.replace(
        cfg,
        service=dataclasses.replace(cfg.service, estimator="batch", accuracy_limit_mm=0.3),
        results=dataclasses.replace(cfg.results, dir="results", station="7"),
        line=dataclasses.replace(cfg.line, slots_per_window=2),
        simline=dataclasses.replace(
            cfg.simline, warmup_k=0.0, period_s=PERIOD_S, window_s=WINDOW_S,
            knock_at_s=KNOCK_AT_S, knock_kind="sensor", knock_mm=0.3,
        ),
    )  # fmt: skip
    events: list[dict[str, Any]] = []
    with (
        hold_state(state.root),
        SimulatedLineRun(cfg, state.root, seed=SEED, geometric=True, plan=state.plan) as run,
    ):
        run.run_windows(WINDOWS, on_event=events.append)
        history = list(run.line.plc.history)
        first_body = run.line.settings.first_body
        sigma_mm = run.service.settings.recalib.jump_sigma_mm  # resolved at its start
        epoch = run.clock.start_epoch
    yield {
        "state": state, "events": events, "history": history, "first_body": first_body,
        "epoch": epoch, "cfg": cfg, "sigma_mm": sigma_mm,
    }  # fmt: skip


def _truth(state: StateDir, cfg: Any) -> tuple[Any, BodyShop]:
    from app.inspect.plan import load_features

    plan = load_features(state.root / "features.toml", cfg.T_part_base)
    return plan, BodyShop(nominal_features(plan), BuildProcess(seed=SEED))


def test_each_clamped_body_is_measured_stored_and_told_to_the_plc(line_run: dict[str, Any]) -> None:
    state, cfg = line_run["state"], line_run["cfg"]
    plan, shop = _truth(state, cfg)
    store = Store.read_only(state.db)
    bodies = store.bodies()
    assert len(bodies) >= WINDOWS - 1
    ids = [b["body_id"] for b in bodies]
    assert ids == list(range(line_run["first_body"], line_run["first_body"] + len(bodies)))
    body_events = [e for e in line_run["events"] if e["event"] == "body"]
    assert [e["body_id"] for e in body_events] == ids
    # the PLC saw body_done for every body, body_nok exactly for the bodies not ok
    done = [o for o in line_run["history"] if o.body_done]
    assert len(done) >= len(bodies)
    as_measured = [store.body_evaluations(b["id"])[0] for b in bodies]
    assert [o.body_nok for o in done][: len(bodies)] == [not e["ok"] for e in as_measured]
    covered, n, errors = 0, 0, []
    for b in bodies:
        if b["t"] - line_run["epoch"] > KNOCK_AT_S - PERIOD_S:
            # the knocked ones (the next test), and the one clamped when the knock came: its
            # features measured after the knock are off by it (it counted as before the knock
            # until a statement tight enough for its 0.15-0.3 mm showed it)
            continue
        values = store.body_values(b["id"], 0)
        assert len(values) == len(plan.characteristics())
        truth = shop.body(b["body_id"] - line_run["first_body"])
        for v, c in zip(values, plan.characteristics(), strict=True):
            assert v["measured_mm"] is not None, v["reason"]
            e = v["measured_mm"] - true_value(truth, c, plan)
            covered += abs(e) <= v["u95_mm"]
            n += 1
            if c.kind == "position":
                errors.append(e)
    store.close()
    # before the knock: the stated U95 covers the true error of the values, which are within a
    # commissioned cell's accuracy of the truth with no offset. 370 values of 5 bodies: a U95
    # that covers 95 % gives at least 92 % with 99 % probability were they independent (the
    # binomial's lower bound); a body's features share its robot's stops, so one body's stops
    # move the whole figure (at 36 commissioning views body 100003 kept 65 % of its positions
    # and the five 93.0 %, at 18 views 98.4 %; the judged coverage is bench/body.py's, 50
    # bodies a seed: 96.6-99.2 % on 202, 203, 206 at 36 views, docs/results/body.md)
    assert covered / n >= 0.92
    assert float(np.sqrt(np.mean(np.square(errors)))) < 0.06


def test_the_stored_raw_data_give_the_stored_values_again(line_run: dict[str, Any]) -> None:
    state, cfg = line_run["state"], line_run["cfg"]
    plan, _ = _truth(state, cfg)
    store = Store.read_only(state.db)
    b = store.bodies()[0]
    cal = Calibration.load(StateDir(state.root).version_file(b["params_version"]))
    raw = raw_of(store.body_raw(b["id"]))
    # the features the robot repeats too little for were measured from several stops, each
    # stop's raw data its own (app.inspect.views); computed again as one
    stops = {(r.feature, r.stop) for r in raw}
    assert any(k > 0 for _, k in stops) and len(stops) == len(raw)
    noise = StopNoise(cfg.robot.repeatability_mm, line_run["sigma_mm"])
    again = evaluate_body(str(b["body_id"]), cal, plan, raw, b["statement_u95_mm"], None, noise)
    stored = store.body_values(b["id"], 0)
    store.close()
    for v, s in zip(again.values, stored, strict=True):
        # float32 raw points: the same values to well below a micrometre
        assert v.measured_mm is not None and abs(v.measured_mm - s["measured_mm"]) < 2e-4
        assert v.decision == s["decision"]


def test_a_corrected_knock_has_its_bodies_computed_again(line_run: dict[str, Any]) -> None:
    state, cfg = line_run["state"], line_run["cfg"]
    plan, shop = _truth(state, cfg)
    store = Store.read_only(state.db)
    (interval,) = [s for s in store.suspects() if s["t_end"] is not None]
    inside = store.bodies(interval["t_start"], interval["t_end"])
    redone = [b for b in inside if b["evaluation"] > 0]
    assert redone and interval["reevaluated"] == len(redone)
    # those not computed again may precede the step: measured before its first moved sphere
    onset_t = store.measurements_by_id([interval["onset_id"]])[0]["t"]
    assert all(b["t"] >= onset_t for b in redone)
    assert interval["not_reevaluated"] == sum(b["t"] < onset_t for b in inside)
    assert interval["decisions_changed"] is not None
    assert [e for e in line_run["events"] if e["event"] == "reevaluated"]
    before: list[float] = []
    after: list[float] = []
    for b in redone:
        assert b["params_version"] == interval["end_version"] and b["suspect_id"] == interval["id"]
        truth = shop.body(b["body_id"] - line_run["first_body"])
        for k, out in ((0, before), (b["evaluation"], after)):
            for v, c in zip(store.body_values(b["id"], k), plan.characteristics(), strict=True):
                if c.kind == "position" and v["measured_mm"] is not None:
                    out.append(v["measured_mm"] - true_value(truth, c, plan))
    store.close()
    rms_before = float(np.sqrt(np.mean(np.square(before))))
    rms_after = float(np.sqrt(np.mean(np.square(after))))
    # the knock moved the knocked bodies' values; the correction brings them back
    assert rms_before > 0.1 and rms_after < 0.06, (rms_before, rms_after)


def test_each_evaluation_is_a_file_in_the_results_directory(line_run: dict[str, Any]) -> None:
    """[results] dir: one AQDEF file a body as measured, one more for each body computed again,
    every one marked written, no temporary file left."""
    state = line_run["state"]
    store = Store.read_only(state.db)
    want = {
        file_name("SIM-BIW-01", b["body_id"], e["evaluation"])
        for b in store.bodies()
        for e in store.body_evaluations(b["id"])
    }
    assert store.unexported() == []
    store.close()
    folder = state.root / "results"
    assert {p.name for p in folder.iterdir()} == want
    assert any(name.endswith("_e1.dfq") for name in want)
    text = (folder / sorted(want)[0]).read_bytes().decode("ascii")
    assert text.startswith("K0100 74\r\nK1001 SIM-BIW-01\r\n") and "K1081 7\r\n" in text
