"""The cell file: one declaration per setting.

Every table of the cell TOML is a frozen section dataclass whose fields are its keys, their
defaults the embedded cell and their metadata the checks (app.config.section); the code that
uses a setting takes the section itself. Where each lives:

    app.config.cell     the cell's geometry, simulation, calibration (with the offline gates)
                        and planning; `CellConfig` and `load_cell`
    app.config.line     the in-line service: [line], [sweep], [drift], [service], [opcua],
                        [simline]
    app.config.devices  [devices], [camera], [commission]
    app.config.check    reading a file's table into its section (file, line, key in errors)
    app.config.write    writing a cell file that reads back to the same values
"""

from app.config.cell import DEFAULTS, SECTIONS, CellConfig, load_cell

__all__ = ["DEFAULTS", "SECTIONS", "CellConfig", "load_cell"]
