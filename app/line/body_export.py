"""The bodies' AQDEF files in the results directory the plant's SPC import watches (`[results]
dir`): one `.dfq` a body and evaluation, `<part>_<body>_e<evaluation>.dfq` (a body computed
again after a correction is written again, as a new file marked so in its values' text).

Each file is written atomically (a hidden temporary file in the same folder, fsynced, renamed:
no importer ever reads half a file), then its evaluation is marked written in the database. The
database is the record: a directory that cannot be written (gone, full, read-only) costs no
result: the files wait, `export_pending` writes them, oldest first, once it can again, and a
file written before a crash but not marked is written again under the same name (replaced, not
duplicated).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from app.formats.aqdef import dfq_text
from app.formats.files import replace_atomically
from app.line.body_results import record_of
from app.line.store import Store


def file_name(part: str, body: object, evaluation: int) -> str:
    """`<part>_<body>_e<evaluation>.dfq`, with anything but letters, digits, '-' and '.' as
    '_'."""
    safe = re.sub(r"[^A-Za-z0-9.\-]", "_", f"{part}_{body}")
    return f"{safe}_e{evaluation}.dfq"


@dataclass(frozen=True)
class ResultsWriter:
    """Writes the bodies' files into `folder` (the station and the part's description in
    each file's header)."""

    folder: Path
    station: tuple[str, str]
    description: str = ""

    def export_pending(self, store: Store, now_t: float, limit: int = 100) -> tuple[int, str]:
        """Write the files not written yet, oldest first (at most `limit`); (how many were
        written, why the next could not be: "" when none failed)."""
        intervals = store.suspects()
        written = 0
        for row, evaluation in store.unexported(limit):
            (body,) = store.bodies(row=row, evaluation=evaluation)
            rec = record_of(store, body, intervals, now_t)
            path = self.folder / file_name(rec["part"], rec["body"], evaluation)
            text = dfq_text(rec["part"], self.description, [rec], self.station)
            try:
                self.folder.mkdir(parents=True, exist_ok=True)
                replace_atomically(path, text.encode("ascii"))
            except OSError as exc:
                return written, f"{self.folder}: {exc.strerror or exc}"
            store.mark_exported(row, evaluation, now_t)
            written += 1
        return written, ""
