"""The bodies' AQDEF files in the results directory the plant's SPC import watches (`[results]
dir`): one `.dfq` a body and evaluation, `<part>_<body>_e<evaluation>.dfq` (a body computed
again after a correction is written again, as a new file marked so in its values' text).

Each file is written atomically (a hidden temporary file in the same folder, fsynced, renamed:
no importer ever reads half a file), then its evaluation is marked written in the database. The
database is the record: a directory that cannot be written (gone, full, read-only) costs no
result: the files wait, `export_pending` writes them, oldest first, once it can again, and a
file written before a crash but not marked is written again under the same name (replaced, not
duplicated).

Retention (`retain_bodies`, the service's hourly pass): the bodies older than `[results]
keep_days` are deleted from the database with their evaluations, values and raw data, and the
files rvis wrote of them (by the names `file_name` gives) are removed from the results
directory first; a body is kept while a suspect interval still open holds it or a file of it
waits to be written, and while its files cannot be removed (tried again at the next pass). At
most 1000 bodies a pass (about 1 ms each with its files: a backlog drains over a few hours, the
loop never held long); the database's freed pages are used again (it does not shrink).
"""

from __future__ import annotations

import contextlib
import logging
import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from app.formats.aqdef import dfq_text
from app.formats.files import replace_atomically
from app.line.body_results import record_of
from app.line.store import Store

if TYPE_CHECKING:
    from app.line.settings import ServiceSettings

DAY_S = 86400.0


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


def retain_bodies(
    store: Store, settings: ServiceSettings, now_t: float, log: logging.Logger
) -> tuple[int, int]:
    """Delete the bodies measured more than `settings.results_keep_days` before `now_t` (0:
    none), their files in `settings.results_dir` removed first (module docstring); (bodies
    deleted, files removed)."""
    days, folder = settings.results_keep_days, settings.results_dir
    if days <= 0:
        return 0, 0
    expired = store.expired_bodies(now_t - days * DAY_S, keep_unexported=folder is not None)
    gone: list[int] = []
    files = 0
    for b in expired:
        names = [file_name(b["part"], b["body_id"], e) for e in b["files"]]
        paths = [] if folder is None else [folder / name for name in names]
        try:
            for path in paths:
                # gone already (the plant's import moved it): nothing to remove
                with contextlib.suppress(FileNotFoundError):
                    path.unlink()
                    files += 1
        except OSError as exc:
            log.warning("retention: %s: %s (tried again at the next pass)", folder, exc)
            break
        gone.append(int(b["id"]))
    n = store.delete_bodies(gone)
    if n:
        log.info("retention: %d bodies older than %g days deleted, %d files", n, days, files)
    return n, files
