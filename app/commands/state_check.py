"""`rvis state check` (app/commands/state.py): read-only findings about a state directory
(integrity, schema, parameters against the history and the database, the files the
commissioning wrote, permissions and the operators' group, free space, the lock holder, the
sizes)."""

from __future__ import annotations

import json
import stat
from pathlib import Path
from typing import Any

from app.commands.state_backup import database_summary, names_another_state_dir
from app.errors import InputError


def check(state: Any, min_free_mb: float, group: str | None = None) -> dict[str, Any]:
    """Read-only findings about the state directory `state` (a StateDir); `group`: the
    operators' group its files should follow ("" none; None: the directory's own when it is
    setgid, as the service makes it with one)."""
    from app.line.statedir import disk_usage_mb, holder_pid

    if not state.root.is_dir():
        raise InputError("no such state directory", file=state.root)
    problems: list[str] = []
    out: dict[str, Any] = {"state_dir": str(state.root), "problems": problems}
    pid = holder_pid(state)
    out["service_pid"] = pid
    out["database"] = _check_database(state, problems)
    out["parameters"] = _check_parameters(state, out["database"], problems)
    out["commissioned"] = _check_commissioned(state, out["database"], problems)
    out["permissions"] = _check_permissions(state, problems)
    out["group"] = _check_group(state, group, problems)
    out["free_mb"] = round(state.free_mb(), 1)
    if out["free_mb"] < min_free_mb:
        problems.append(f"{out['free_mb']:.0f} MB free, below min_free_mb = {min_free_mb:.0f}")
    out["size_mb"] = round(disk_usage_mb(state.root), 3)
    return out


def _check_database(state: Any, problems: list[str]) -> dict[str, Any]:
    from app.line.store import SCHEMA_VERSION, StorageError, Store

    if not state.db.is_file():
        problems.append(f"{state.db}: missing")
        return {}
    out: dict[str, Any] = {"path": str(state.db), "bytes": state.db.stat().st_size}
    if out["bytes"] and not _sqlite_header(state.db):
        # damaged whatever a write-ahead log beside it still holds (SQLite reads the pages the
        # log has from the log, and may find no fault before the log is folded in)
        problems.append(f"{state.db}: damaged: not an SQLite database file (its header)")
        return out
    try:
        out.update(database_summary(state.db))
        store = Store.read_only(state.db)
        try:
            out["tables_bytes"] = store.table_bytes()
        finally:
            store.close()
    except (InputError, StorageError) as exc:  # not a database; not this user's to read
        problems.append(str(exc))
        return out
    if out["integrity"] != ["ok"]:
        problems.append(f"{state.db}: integrity check: {'; '.join(out['integrity'])}")
    if out["schema"] > SCHEMA_VERSION:
        problems.append(f"{state.db}: schema {out['schema']} is newer than this rvis's")
    return out


def _sqlite_header(path: Path) -> bool:
    """The file starts as an SQLite database file does (unreadable: said to, the open says
    why)."""
    try:
        with path.open("rb") as f:
            return f.read(16) == b"SQLite format 3\x00"
    except OSError:
        return True


def _check_parameters(state: Any, db: dict[str, Any], problems: list[str]) -> dict[str, Any]:
    try:
        out: dict[str, Any] = {"history_versions": len(state.versions())}
    except OSError as exc:  # an operator where the group is not followed yet
        problems.append(f"{state.history}: unreadable ({exc.strerror or exc})")
        out = {"history_versions": "?"}
    try:
        current = json.loads(state.current.read_text(encoding="utf-8"))
        version = int(current["history_version"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        problems.append(f"{state.current}: unreadable ({exc}); the service rebuilds it")
        return out
    out["current_version"] = version
    try:
        same = current == json.loads(state.version_file(version).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        same = False
    if not same:
        problems.append(f"{state.current}: not history version {version}")
    applied = db.get("applied_version")
    if applied is not None and applied != version:
        problems.append(
            f"{state.current}: version {version}, the database has {applied} in force"
            " (the service completes or rebuilds it at start)"
        )
    return out


def _check_commissioned(state: Any, db: dict[str, Any], problems: list[str]) -> dict[str, Any]:
    """When `rvis commission` made this directory (its database records the commissioning's
    apply), the files its last step wrote for `rvis run`: without sensor.toml the service
    measures with the design sensor model, without cell.toml or plan.json it does not start
    as commissioned."""
    named = names_another_state_dir(state)
    if named is not None:
        problems.append(
            f"{state.cell}: [service] state_dir names {named}, not this directory: a command"
            f" given --cell {state.cell} would use that one (name this directory there; `rvis"
            " state restore` does)"
        )
    if not db.get("commissioned"):
        return {"by_commissioning": False}
    missing = [p.name for p in state.commissioned if not p.is_file()]
    for name in missing:
        problems.append(
            f"{state.root / name}: missing, although rvis commission wrote it (restore it from"
            " a backup, or run the commissioning's last step again)"
        )
    return {"by_commissioning": True, "missing": missing}


def _check_permissions(state: Any, problems: list[str]) -> dict[str, str]:
    out: dict[str, str] = {}
    for path in (state.root, state.db, state.current, state.socket):
        try:
            mode = stat.S_IMODE(path.stat().st_mode)
        except OSError:
            continue
        out[path.name or str(path)] = f"{mode:04o}"
        if mode & 0o007:
            problems.append(f"{path}: mode {mode:04o} gives others access")
    try:
        mode = stat.S_IMODE(state.opcua_key.stat().st_mode)
    except OSError:
        return out
    out[state.opcua_key.name] = f"{mode:04o}"
    if mode & 0o077:
        problems.append(f"{state.opcua_key}: mode {mode:04o}: the OPC UA private key must be 0600")
    return out


def _check_group(state: Any, group: str | None, problems: list[str]) -> dict[str, Any] | None:
    """Whether what the directory holds follows the operators' group (a directory
    commissioned before `[service] operators_group` was set does not: operators' TUI history
    and `rvis state` fail), and the one line that fixes it."""
    import grp

    from app.line.statedir import group_fix_command, group_strays

    if group is None:  # the group the service gave the directory, if any
        st = state.root.stat()
        if not st.st_mode & stat.S_ISGID:
            return None
        group = _group_name(st.st_gid)
    if not group:
        return None
    try:
        gid = grp.getgrnam(group).gr_gid
    except KeyError:
        gid = int(group) if group.isdigit() else -1
    if gid < 0:
        problems.append(f"[service] operators_group: no such group {group!r}")
        return {"name": group, "strays": None}
    strays = group_strays(state, gid)
    if strays:
        first = strays[0]
        st = first.lstat()
        owner = f"group {_group_name(st.st_gid)}, mode {stat.S_IMODE(st.st_mode):04o}"
        problems.append(
            f"{len(strays)} entries do not follow the operators' group {group} (e.g. {first}:"
            f" {owner}), operators cannot read them; fix: restart the service (it sets group"
            f" and modes at start), or as root: {group_fix_command(state, group)}"
        )
    return {"name": group, "strays": len(strays)}


def _group_name(gid: int) -> str:
    import grp

    try:
        return grp.getgrgid(gid).gr_name
    except KeyError:
        return str(gid)


def check_report(f: dict[str, Any]) -> str:
    db, params = f["database"], f["parameters"]
    pid = f["service_pid"]
    integrity = "; ".join(db.get("integrity", ["unknown"]))
    m = db.get("measurements")
    counts = "?" if not m else f"{m.get('ok', 0)} ok, {m.get('rejected', 0)} rejected"
    commissioned = f.get("commissioned", {})
    made_by = "no (no file of rvis commission expected)"
    if commissioned.get("by_commissioning"):
        missing = commissioned.get("missing") or []
        made_by = "by rvis commission: " + (
            f"{', '.join(missing)} missing" if missing else "its cell, sensor and plan files here"
        )
    lines = [
        f"state directory  {f['state_dir']} ({f['size_mb']:.1f} MB, {f['free_mb']:.0f} MB free)",
        "service          " + ("not running" if pid is None else f"running (pid {pid})"),
        f"database         schema {db.get('schema', '?')}, integrity {integrity},"
        f" measurements {counts}",
        f"parameters       current version {params.get('current_version', '?')},"
        f" {params['history_versions']} in the history, in force by the database"
        f" {db.get('applied_version', '?')}",
        f"commissioned     {made_by}",
        f"permissions      {', '.join(f'{k} {v}' for k, v in f['permissions'].items())}",
    ]
    group = f.get("group")
    if group is not None:
        strays = group["strays"]
        follows = "every entry follows it" if strays == 0 else f"{strays} entries do not follow it"
        lines.append(
            f"operators group  {group['name']}: {'unknown' if strays is None else follows}"
        )
    sizes = db.get("tables_bytes", {})
    if sizes:
        top = sorted(sizes.items(), key=lambda kv: -kv[1])
        lines.append("sizes            " + ", ".join(f"{k} {v / 1024:.0f} KiB" for k, v in top))
    problems = f["problems"]
    lines.append("result           " + ("ok" if not problems else f"{len(problems)} problem(s)"))
    lines += [f"  - {p}" for p in problems]
    return "\n".join(lines)
