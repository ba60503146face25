"""The cell file: one declaration per setting.

Every section of the cell TOML is a frozen dataclass whose fields are its keys, their defaults
the embedded cell and their metadata the checks (app.config.section). The cell's geometry,
simulation, calibration and planning sections are in app.config.cell with the resolved
`CellConfig` and `load_cell`; the reader that checks a file is app.config.check, the TOML
reading app.config.tomlfile, the writer app.config.write.
"""

from app.config.cell import (
    DEFAULTS,
    SECTIONS,
    CameraSection,
    CellConfig,
    LineSection,
    OpcUaSection,
    SpheresSection,
    load_cell,
)

__all__ = [
    "DEFAULTS",
    "SECTIONS",
    "CameraSection",
    "CellConfig",
    "LineSection",
    "OpcUaSection",
    "SpheresSection",
    "load_cell",
]
