"""`rvis state backup|restore|check|suspects|body`: the service's state directory as something
an operator can carry (docs/operations.md).

- `backup DEST`: a consistent copy while the service runs (SQLite's online backup of `rvis.db`,
  then what `StateDir.carried()` names: the parameter history, `current.json`, the plan, the
  commissioned `cell.toml` and `sensor.toml`, `commission/` and the OPC UA server's
  certificate, key and trusted clients), checked, with a `backup.json` manifest. The history
  is copied after the database, so it holds every version the copied database names.
- `restore BACKUP`: a backup into a state directory that no service holds and that has no
  database (a damaged one is moved aside by a person first: rvis never overwrites a database).
- `suspects [--since T] [--json]`: the suspect intervals (app/line/step.py): from the last
  trustworthy measurement before a step to the apply of its correction, when the calibration in
  force was wrong, with its estimated size and the bodies measured then (their ids as the line
  PLC gives them, `[line] plc_body_id`), for the inspection software to re-measure or flag.
- `body BODY [--json]`: how sure the measurement of one body is (app/commands/state_body.py):
  the window it was clamped in, the parameters version in force then, the U95 the cell stated
  for its bodies, the suspect intervals it falls in, and its values with their U95 when the
  cell measured it.
- `check`: read-only findings about a state directory (integrity, schema, parameters against the
  history and the database, the files the commissioning wrote, permissions, free space, the
  lock holder, the sizes); exit 1 when something is wrong. With an operators' group (`--cell`'s
  `[service] operators_group`, else the group of a setgid directory, as the service leaves it)
  files that do not follow it are a problem, with the one line that fixes them.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import stat
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from app.commands import add_command
from app.commands.status import state_dir_of
from app.errors import InputError


def register(sub: Any) -> None:
    p = add_command(sub, "state")
    p.add_argument("--cell", help="cell configuration TOML (for [service] state_dir)")
    p.add_argument("--state-dir", help="state directory (default: [service] state_dir)")
    verbs = p.add_subparsers(dest="verb", metavar="VERB", parser_class=type(p))
    verbs.required = True
    b = verbs.add_parser("backup", help="copy the state while the service runs")
    b.add_argument("dest", help="new (or empty) folder for the copy")
    b.add_argument("--json", action="store_true", help="print the manifest as JSON")
    r = verbs.add_parser("restore", help="a backup into a state directory with no database")
    r.add_argument("backup", help="folder written by `rvis state backup`")
    c = verbs.add_parser("check", help="check a state directory (read-only)")
    c.add_argument("--json", action="store_true", help="print the findings as JSON")
    s = verbs.add_parser(
        "suspects", help="when the calibration in force was wrong after a step (read-only)"
    )
    s.add_argument(
        "--since",
        help="intervals open or ending at or after this UTC time (2026-11-25T06:00:00) or age"
        " (90m, 8h, 2d); default: all",
    )
    s.add_argument("--json", action="store_true", help="print the intervals as JSON")
    bd = verbs.add_parser("body", help="how sure the measurement of one body is (read-only)")
    bd.add_argument("body", help="the body's id (as the PLC gave it)")
    bd.add_argument("--json", action="store_true", help="print the answer as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from app.line.statedir import StateDir

    state = StateDir(state_dir_of(args))
    if args.verb == "backup":
        manifest = backup(state, Path(args.dest))
        print(json.dumps(manifest, indent=1) if args.json else _backup_text(manifest, args.dest))
        return 0
    if args.verb == "suspects":
        since = None if args.since is None else parse_since(args.since, time.time())
        rows = suspects(state, since)
        print(json.dumps(rows, indent=1) if args.json else _suspects_table(rows))
        return 0
    if args.verb == "body":
        from app.commands.state_body import body_answer, body_text

        doc = body_answer(state, args.body, time.time())
        print(json.dumps(doc, indent=1) if args.json else body_text(doc))
        return 0
    if args.verb == "restore":
        restore(Path(args.backup), state)
        print(f"restored {args.backup} into {state.root}")
        return 0
    min_free_mb, group = _service_settings(args)
    findings = check(state, min_free_mb, group)
    if args.json:
        print(json.dumps(findings, indent=2))
    else:
        print(_report(findings))
    return 0 if not findings["problems"] else 1


def _service_settings(args: argparse.Namespace) -> tuple[float, str | None]:
    """The cell file's [service] min_free_mb and operators_group; without `--cell` the
    default and None (no file loaded: the directory's own group is checked)."""
    if args.cell is None:
        from app.state_defaults import MIN_FREE_MB

        return MIN_FREE_MB, None
    from app.config import load_cell

    service = load_cell(args.cell).service
    return float(service.min_free_mb), str(service.operators_group)


# -- backup and restore ---------------------------------------------------------------------
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
            **_database_summary(copy.db),
            "history_versions": len(copy.versions()),
            "files": files,
        }
        copy.manifest.write_text(json.dumps(manifest, indent=1) + "\n", encoding="utf-8")
    finally:
        os.umask(old_umask)
    if manifest["integrity"] != ["ok"]:
        raise InputError(f"the copy fails its integrity check: {manifest['integrity']}", file=dest)
    return manifest


def _backup_text(manifest: dict[str, Any], dest: str) -> str:
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


def _database_summary(db: Path) -> dict[str, Any]:
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


def restore(backup_dir: Path, state: Any) -> list[str]:
    """A backup into `state` (a StateDir): refused while a service holds it or when it has a
    database of its own; the files put back besides the database."""
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
    summary = _database_summary(copy.db)
    if summary["integrity"] != ["ok"]:
        raise InputError(f"the backup is damaged: {summary['integrity']}", file=copy.db)
    state.root.mkdir(mode=0o750, parents=True, exist_ok=True)
    old_umask = os.umask(0o027)
    try:
        files = _copy_carried(copy, state)
        tmp = state.db.with_name(f".{state.db.name}.restore")
        shutil.copyfile(copy.db, tmp)
        os.replace(tmp, state.db)  # the database last: a half restore has none
    finally:
        os.umask(old_umask)
    return files


# -- check ------------------------------------------------------------------------------------
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
        out.update(_database_summary(state.db))
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


def _report(f: dict[str, Any]) -> str:
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


# -- suspect intervals -------------------------------------------------------------------------
def parse_since(text: str, now: float) -> float:
    """`--since`: an ISO 8601 UTC time ("2026-11-25", "2026-11-25T06:00:00") or an age
    ("90m", "8h", "2d"); the Unix time it stands for. InputError naming the field otherwise."""
    units = {"s": 1.0, "m": 60.0, "h": 3600.0, "d": 86400.0}
    t = text.strip()
    if t[-1:] in units:
        try:
            age = float(t[:-1])
        except ValueError:
            age = -1.0
        if age >= 0 and math.isfinite(age):
            return now - age * units[t[-1]]
    try:
        when = datetime.fromisoformat(t)
    except ValueError:
        raise InputError(
            f"{text!r} is neither a UTC time (2026-11-25T06:00:00) nor an age (90m, 8h, 2d)",
            field="--since",
        ) from None
    return (when if when.tzinfo else when.replace(tzinfo=UTC)).timestamp()


def suspects(state: Any, since_t: float | None) -> list[dict[str, Any]]:
    """The suspect intervals of the state directory (open ones always, closed ones ending at or
    after `since_t`), as the service's events carry them (app.line.states.suspect_json)."""
    from app.line.states import suspect_json
    from app.line.store import Store

    if not state.db.is_file():
        raise InputError("no service state here (no rvis.db)", file=state.root)
    store = Store.read_only(state.db)
    try:
        return [suspect_json(r) for r in store.suspects(since_t)]
    finally:
        store.close()


def _suspects_table(rows: list[dict[str, Any]]) -> str:
    """One line per interval, then its bodies whole (wrapped), when the PLC names them."""
    import textwrap

    from app.line.states import bodies_text

    if not rows:
        return "no suspect intervals"
    lines = [f"{'id':>4}  {'from (UTC)':<25} {'to (UTC)':<25} {'size mm':>8}  {'bodies':<8}  what"]
    for r in rows:
        size = "-" if r["size_mm"] is None else f"{r['size_mm']:.3f}"
        bodies = r.get("bodies") or []
        lines.append(
            f"{r['id']:>4}  {r['start_utc']:<25} {r['end_utc'] or 'open':<25} {size:>8}"
            f"  {len(bodies):<8}  {r['text'] or ''}"
        )
        if bodies:
            text = f"bodies ({bodies_text(bodies)}): {', '.join(map(str, bodies))}"
            lines += textwrap.wrap(text, 96, initial_indent="      ", subsequent_indent="        ")
    return "\n".join(lines)
