"""app/cellfile.py: a cell written out reads back to the same sections (the commissioning's
cell.toml), with sphere ids that need quoting and the tracker's positions in the part frame."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from app.config import SECTIONS, load_cell
from app.config.cell import SpheresSection
from app.config.devices import CameraSection
from app.config.write import dumps_cell


def test_a_cell_reads_back_to_the_same_sections(tmp_path: Path) -> None:
    cfg = load_cell(None)
    spheres: dict[str, tuple[float, ...]] = {"P1": (1.5, -2.25, 3.0), "stand 2": (-1e4, 0.1, 1e-3)}
    cfg = dataclasses.replace(
        cfg,
        spheres=SpheresSection(frame="part", positions_mm=spheres),
        camera=CameraSection(exposure_us=12345.5, gain_db=3.0),
    )
    path = tmp_path / "cell.toml"
    path.write_text(dumps_cell(cfg, "written by a test\nsecond line"))
    again = load_cell(path)
    for cls in SECTIONS:
        assert dict(getattr(again, cls.name)) == dict(getattr(cfg, cls.name)), cls.name
    assert path.read_text().startswith("# written by a test\n# second line\n")
    np.testing.assert_array_equal(again.spheres_part_mm["stand 2"], spheres["stand 2"])
    np.testing.assert_allclose(again.T_part_base, cfg.T_part_base, atol=0)


def test_only_finite_numbers_are_written() -> None:
    cfg = load_cell(None)
    with pytest.raises(ValueError, match="finite"):  # refused where the section is made
        dumps_cell(dataclasses.replace(cfg, camera=CameraSection(exposure_us=float("nan"))))
