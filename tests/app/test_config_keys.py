"""Every cell-file key of the service reaches it (issue 22: one declaration per setting, no
key silently dropped on its way): each key set to a value other than its default arrives in
ServiceSettings value for value, the gates converted once."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, cast

import pytest

from app.config import SECTIONS, load_cell
from app.config.section import Section
from app.line.settings import ServiceSettings, from_cell

SERVICE_TABLES = ("line", "sweep", "drift", "service", "opcua")


def _other_value(section: type[Section], f: dataclasses.Field[Any]) -> Any:
    """A valid value of the key that differs from its default."""
    default, meta = getattr(section(), f.name), f.metadata
    if isinstance(default, bool):
        return not default
    if isinstance(default, str):
        choices = meta.get("choices") or ()
        return next((c for c in choices if c != default), None)
    if isinstance(default, int | float):
        hi = meta.get("hi")
        # the first that the section accepts (rolling_size: 0 by the model, else at least 10)
        tries = (default + 1, default + 10) if isinstance(default, int) else (default * 0.5 or 0.5,)
        for value in tries:
            if hi is not None and value > hi:
                continue
            try:
                section(**{f.name: value})
            except ValueError:
                continue
            return value
    return None


def _toml(value: Any) -> str:
    return str(value).lower() if isinstance(value, bool) else repr(value).replace("'", '"')


def test_every_service_key_arrives_in_the_service_settings(tmp_path: Path) -> None:
    lines: list[str] = []
    expected: dict[tuple[str, str], Any] = {}
    for section in SECTIONS:
        if section.name not in SERVICE_TABLES:
            continue
        lines.append(f"[{section.name}]")
        for f in dataclasses.fields(cast(Any, section)):
            value = _other_value(section, f)
            if value is None or f.name in ("enabled", "schedule", "state_dir", "operators_group"):
                continue  # no other valid value alone (opcua needs its endpoint, ...)
            lines.append(f"{f.name} = {_toml(value)}")
            expected[(section.name, f.name)] = value
    cell = tmp_path / "cell.toml"
    cell.write_text("\n".join(lines) + "\n", encoding="utf-8")
    s = from_cell(load_cell(cell))
    parts: list[Any] = [s.line, s.sweep, s.drift, s.recalib, s.ops, s.opcua]
    seen: dict[tuple[str, str], Any] = {}
    for part in parts:
        for f in dataclasses.fields(part):
            seen[(part.name, f.name)] = getattr(part, f.name)
    gate_keys = {k for k in expected if k[0] == "service" and k[1].startswith("max_")}
    missing = [k for k in expected if k not in seen and k not in gate_keys]
    assert not missing, f"keys that no part of ServiceSettings carries: {missing}"
    wrong = [(k, v, seen[k]) for k, v in expected.items() if k in seen and seen[k] != v]
    assert not wrong
    # the in-line gates, converted once (degrees in the file, radians in calib)
    svc = dict(load_cell(cell).service)
    assert s.gates.max_holdout_ratio == svc["max_holdout_ratio"]
    assert s.gates.max_base_change_rad == pytest.approx(
        svc["max_base_change_deg"] * 3.14159265 / 180
    )
    assert isinstance(s, ServiceSettings)


@pytest.mark.parametrize(
    ("text", "offline", "in_line"),
    [
        ("", "rigid", "compliant"),  # the defaults (the service's: the knock campaign, issue 28)
        ('[calibration]\nmodel = "rigid"\n', "rigid", "rigid"),  # a file from before the key
        ('[calibration]\nmodel = "compliant"\n', "compliant", "compliant"),
        ('[service]\nmodel = "rigid"\n', "rigid", "rigid"),
        ('[calibration]\nmodel = "compliant"\n[service]\nmodel = "rigid"\n', "compliant", "rigid"),
        ('[calibration]\nmodel = "rigid"\n[service]\nmodel = "compliant"\n', "rigid", "compliant"),
    ],
)
def test_the_service_model_is_its_own_key_and_an_older_file_keeps_its_model(
    tmp_path: Path, text: str, offline: str, in_line: str
) -> None:
    """[service] model is what the service identifies, [calibration] model what identify, the
    plan and the commissioning fit; a cell file that sets only [calibration] model (every file
    written before [service] model existed) keeps its service on that model."""
    path = tmp_path / "cell.toml"
    path.write_text(text)
    cfg = load_cell(path)
    assert cfg.service.model == in_line and cfg.service_model().kind == in_line
    assert cfg.calibration.model == offline and cfg.identification_model().kind == offline
