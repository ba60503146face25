"""`rvis state backup|restore` (app/commands/state.py): a consistent copy of the state directory
while the service runs, with its manifest, and a backup restored into a state directory that
no service holds and that has no database (docs/operations.md)."""

from __future__ import annotations

import json
import os
import shutil
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, NamedTuple

from app.errors import InputError


def _new_folder(path: Path) -> None:
    if path.exists() and (not path.is_dir() or any(path.iterdir())):
        raise InputError("exists and is not an empty folder", file=path)
    try:
        path.mkdir(mode=0o750, parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create it: {exc.strerror or exc}", file=path) from exc


def _copy_carried(src: Any, dst: Any) -> list[str]:
    """Copy what a backup carries besides the database (`StateDir.carried()`: the history
    first, then current.json, the plan, cell.toml, sensor.toml, commission/, the OPC UA
    server's identity) from the StateDir `src` to `dst`; their paths relative to the root."""
    private = set(src.private)
    copied = []
    for f in src.carried():
        rel = f.relative_to(src.root)
        target = dst.root / rel
        target.parent.mkdir(mode=0o750, parents=True, exist_ok=True)
        shutil.copyfile(f, target)
        if f in private:
            os.chmod(target, 0o600)
        copied.append(rel.as_posix())
    return copied


def backup(state: Any, dest: Path) -> dict[str, Any]:
    """Copy the state directory `state` (a StateDir) to `dest`; the manifest."""
    from app.line.statedir import StateDir
    from app.line.store import Store

    if not state.db.is_file():
        raise InputError("no service state here (no rvis.db)", file=state.root)
    _new_folder(dest)
    copy = StateDir(dest)
    old_umask = os.umask(0o027)
    try:
        source = Store.read_only(state.db)
        try:
            source.backup(copy.db)
        finally:
            source.close()
        files = _copy_carried(state, copy)
        manifest = {
            "created_utc": datetime.now(UTC).isoformat(timespec="seconds"),
            "source": str(state.root.resolve()),
            **database_summary(copy.db),
            "history_versions": len(copy.versions()),
            "files": files,
        }
        copy.manifest.write_text(json.dumps(manifest, indent=1) + "\n", encoding="utf-8")
    finally:
        os.umask(old_umask)
    if manifest["integrity"] != ["ok"]:
        raise InputError(f"the copy fails its integrity check: {manifest['integrity']}", file=dest)
    return manifest


def backup_text(manifest: dict[str, Any], dest: str) -> str:
    """What a backup holds, in words (`--json`: the manifest itself)."""
    from app.line.statedir import StateDir

    m = manifest["measurements"]
    version = manifest["applied_version"]
    return (
        f"backed up {manifest['source']} to {dest} ({manifest['created_utc']})\n"
        f"  database    schema {manifest['schema']}, integrity"
        f" {'; '.join(manifest['integrity'])}, measurements {m.get('ok', 0)} ok,"
        f" {m.get('rejected', 0)} rejected\n"
        f"  parameters  version {'-' if version is None else version} in force,"
        f" {manifest['history_versions']} in the history\n"
        f"  files       {len(manifest['files'])} besides the database"
        f" (listed in {StateDir(dest).manifest})"
    )


def database_summary(db: Path) -> dict[str, Any]:
    """A database read-only: its integrity, schema, the version applied last, whether it was
    commissioned, and its rows per table."""
    from app.line.store import Store

    store = Store.read_only(db)
    try:
        applied = store.applied()
        return {
            "integrity": store.integrity_problems() or ["ok"],
            "schema": store.version(),
            "applied_version": int(applied[-1]["version"]) if applied else None,
            "commissioned": any(a["source"] == "commissioning" for a in applied),
            "measurements": store.counts(),
        }
    finally:
        store.close()


class Restored(NamedTuple):
    """What `restore` put back: the files besides the database, and the state directory the
    restored cell file named before it was made to name this one (None: it named none other)."""

    files: list[str]
    cell_named: Path | None


def restore(backup_dir: Path, state: Any) -> Restored:
    """A backup into `state` (a StateDir): refused while a service holds it or when it has a
    database of its own (a cell file that names another state directory made to name this
    one: `point_cell_here`)."""
    from app.line.statedir import StateDir, holder_pid

    copy = StateDir(backup_dir)
    if not copy.manifest.is_file() or not copy.db.is_file():
        raise InputError("not a backup made by `rvis state backup`", file=backup_dir)
    pid = holder_pid(state)
    if pid is not None:
        raise InputError(f"a service runs on it (pid {pid}): stop it first", file=state.root)
    if state.db.exists():
        raise InputError(
            "has a database: move the state directory (or its rvis.db) aside first",
            file=state.root,
        )
    summary = database_summary(copy.db)
    if summary["integrity"] != ["ok"]:
        raise InputError(f"the backup is damaged: {summary['integrity']}", file=copy.db)
    state.root.mkdir(mode=0o750, parents=True, exist_ok=True)
    old_umask = os.umask(0o027)
    try:
        files = _copy_carried(copy, state)
        named = point_cell_here(state)
        tmp = state.db.with_name(f".{state.db.name}.restore")
        shutil.copyfile(copy.db, tmp)
        os.replace(tmp, state.db)  # the database last: a half restore has none
    finally:
        os.umask(old_umask)
    return Restored(files, named)


def names_another_state_dir(state: Any) -> Path | None:
    """The other state directory the cell file in `state` (a StateDir) names explicitly
    (`[service] state_dir`, as `rvis commission` writes it); None when it names this one or
    none."""
    import tomllib

    try:
        doc = tomllib.loads(state.cell.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return None
    named = (doc.get("service") or {}).get("state_dir")
    if not isinstance(named, str) or not named or Path(named).resolve() == state.root.resolve():
        return None
    return Path(named)


def point_cell_here(state: Any) -> Path | None:
    """A restored cell file that names another state directory (the one it was backed up
    from, written there by `rvis commission`) rewritten to name this one, so that `--cell
    DIR/cell.toml` finds this directory and not the old one; the old name (None: unchanged)."""
    named = names_another_state_dir(state)
    if named is None:
        return None
    here = state.root.resolve()
    import dataclasses

    from app.config import load_cell
    from app.config.write import dumps_cell
    from app.formats.files import write_text

    cfg = load_cell(state.cell)
    cfg = dataclasses.replace(cfg, service=dataclasses.replace(cfg.service, state_dir=str(here)))
    kept = []  # the file's leading comment (what wrote it)
    for line in state.cell.read_text(encoding="utf-8").splitlines():
        if not line.startswith("#"):
            break
        kept.append(line[1:].strip())
    note = f"restored by rvis state restore: [service] state_dir was {named}"
    write_text(state.cell, dumps_cell(cfg, "\n".join([*kept, note])))
    return named
