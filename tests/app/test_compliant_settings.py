"""The compliant model's settings have one home (issue 40, "one home"): the cell file's
`[calibration]` keys take their defaults and ranges from calib.compliance_settings, so a value
the cell file accepts builds the model, and one the model refuses is refused where the file is
read (file, line, key) instead of a bare ValueError later (it was: `expansion_per_k = 1e-4`
passed the cell check and failed in the model)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from app.config import load_cell
from app.config.cell import CalibrationSection
from app.errors import InputError
from calib.compliance_settings import RANGES, CompliantSettings


def test_the_cell_file_takes_the_model_s_defaults_and_ranges() -> None:
    fields = {f.name: f for f in dataclasses.fields(CalibrationSection)}
    for name, (lo, hi) in RANGES.items():
        meta = fields[name].metadata
        assert fields[name].default == getattr(CompliantSettings(), name), name
        assert meta["hi"] == hi and lo in (meta["lo"], meta["gt"]), name


@pytest.mark.parametrize("edge", [0, 1])
def test_every_range_edge_the_file_accepts_builds_the_model(tmp_path: Path, edge: int) -> None:
    lines = ["[calibration]", 'model = "compliant"']
    for name, bounds in RANGES.items():
        value = bounds[edge]
        if name == "min_temp_span_k" and edge == 0:
            value = 0.5  # above its low end, which is excluded
        lines.append(f"{name} = {value!r}")
    cell = tmp_path / "cell.toml"
    cell.write_text("\n".join(lines) + "\n")
    model = load_cell(cell).identification_model()  # no ValueError
    assert model.settings.expansion_per_k == RANGES["expansion_per_k"][edge]


def test_beyond_a_range_the_file_names_the_line(tmp_path: Path) -> None:
    cell = tmp_path / "cell.toml"
    cell.write_text("[calibration]\nexpansion_per_k = 2e-4\n")
    with pytest.raises(InputError, match=r"cell.toml:2: \[calibration\] expansion_per_k"):
        load_cell(cell)
