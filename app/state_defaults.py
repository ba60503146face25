"""The state directory's defaults: the cell file's `[service]` table falls back to them
(app.config.line) and the commands that only read the directory find them without loading the
cell file's sections (app.line.statedir). No import: both read it."""

from __future__ import annotations

#: the state directory when neither the cell file nor the command line names one
DEFAULT_ROOT = "rvis-state"
#: free space [MB] below which the service raises `low_disk`
MIN_FREE_MB = 200.0
