"""JSON-line logs and the raw-sweep archive."""

from __future__ import annotations

import io
import json
import logging
from pathlib import Path

import numpy as np

from app.line.events import JsonLineFormatter
from app.line.measure import Reading
from app.line.sweeps import SweepArchive


def test_every_log_record_is_one_json_line_with_its_event() -> None:
    stream = io.StringIO()
    handler = logging.StreamHandler(stream)
    handler.setFormatter(JsonLineFormatter())
    log = logging.getLogger("rvis.test.jsonlog")
    log.addHandler(handler)
    log.setLevel(logging.INFO)
    try:
        log.info("window", extra={"event": "window", "data": {"window": 3, "measured": 1}})
        log.warning("plain %s", "text")
    finally:
        log.removeHandler(handler)
    first, second = (json.loads(line) for line in stream.getvalue().splitlines())
    assert first["event"] == "window" and first["data"] == {"window": 3, "measured": 1}
    assert (second["level"], second["msg"]) == ("warning", "plain text") and "event" not in second


def test_the_archive_keeps_the_last_n_sweeps(tmp_path: Path) -> None:
    archive = SweepArchive(tmp_path / "sweeps", keep=2)
    frames = np.zeros((3, 4, 5), np.uint8)
    reading = Reading(np.zeros(3), {}, frames, np.array([-1.0, 0.0, 1.0]))
    for k in (1, 2, 3):
        frames[0, 0, 0] = k
        assert archive.keep(k, reading) is not None
    assert sorted(p.name for p in (tmp_path / "sweeps").iterdir()) == [
        "00000002.npz",
        "00000003.npz",
    ]
    with np.load(tmp_path / "sweeps" / "00000003.npz") as z:
        assert z["frames"][0, 0, 0] == 3 and list(z["commands_v"]) == [-1.0, 0.0, 1.0]
    assert SweepArchive(tmp_path / "none", keep=0).keep(1, reading) is None
    assert archive.keep(4, Reading(np.zeros(3))) is None  # a geometric reading has no sweep
