"""User-facing errors of the application layer.

    RvisError                 root: anything rvis reports to a user instead of a traceback
    ├── InputError            bad input: a file, line and field that are wrong (exit code 2)
    └── QualityError          a result that fails its quality checks (exit code 3)

The command line prints `str(error)` as one line and exits with `error.exit_code`.
"""

from __future__ import annotations

from pathlib import Path


class RvisError(Exception):
    """Root of the errors rvis reports to a user as one line."""

    exit_code = 1


class InputError(RvisError):
    """Bad input: names the file, the line (1-based, header is line 1) and the field."""

    exit_code = 2

    def __init__(
        self,
        reason: str,
        *,
        file: str | Path | None = None,
        line: int | None = None,
        field: str | None = None,
    ) -> None:
        self.reason = reason
        self.file = None if file is None else str(file)
        self.line = line
        self.field = field
        super().__init__(self._format())

    def _format(self) -> str:
        where = ""
        if self.file is not None:
            where = self.file if self.line is None else f"{self.file}:{self.line}"
        if self.field is not None:
            where = f"{where}: field '{self.field}'" if where else f"field '{self.field}'"
        return f"{where}: {self.reason}" if where else self.reason


class QualityError(RvisError):
    """A computed result failed its quality checks and must not be used."""

    exit_code = 3
