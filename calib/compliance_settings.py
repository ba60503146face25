"""The compliant model's settings (calib/compliance.py) as plain numbers: their defaults and
ranges in one place, read by the model and by the cell file's `[calibration]` section, which
checks a value against the same range when the file is read (file, line and key) instead of the
model refusing it later. No numerics imported: a command that only reads its settings starts
fast."""

from __future__ import annotations

from dataclasses import dataclass

#: Each setting's allowed range, inclusive: (low, high); min_temp_span_k must be > low.
RANGES: dict[str, tuple[float, float]] = {
    "payload_kg": (0.0, 500.0),
    "nominal_compliance_rad_per_nm": (0.0, 1e-5),
    "expansion_per_k": (0.0, 1e-4),
    "min_temp_span_k": (0.0, 100.0),
    "reference_temp_c": (-40.0, 80.0),
}
#: the settings whose low end is excluded
ABOVE_LOW = ("min_temp_span_k",)


@dataclass(frozen=True)
class CompliantSettings:
    """Settings of the compliant model (cell file section `[calibration]`, see the README).

    payload_kg: sensor, cables and bracket at the flange, seeds the payload coefficients;
    nominal_compliance_rad_per_nm: a typical joint compliance, used only with the payload;
    expansion_per_k: the arm's linear expansion coefficient (configured value, the start of
    the identification); identify_expansion: identify it when the measurements span at least
    min_temp_span_k; reference_temp_c: the temperature the geometry refers to. Each within
    RANGES."""

    payload_kg: float = 0.0
    nominal_compliance_rad_per_nm: float = 5e-8
    expansion_per_k: float = 11.5e-6
    identify_expansion: bool = True
    min_temp_span_k: float = 3.0
    reference_temp_c: float = 20.0

    def __post_init__(self) -> None:
        bad = [name for name in RANGES if not in_range(name, getattr(self, name))]
        if bad:
            raise ValueError(f"compliant model settings out of range: {', '.join(bad)}")


def in_range(name: str, value: float) -> bool:
    """The setting `name` may take `value` (RANGES)."""
    lo, hi = RANGES[name]
    return (value > lo if name in ABOVE_LOW else value >= lo) and value <= hi
