"""The service's state directory: its layout (the one place that names its files), its
permissions, the one-service lock and the free space under it (DESIGN.md section 6).

    rvis-state/                  0750 (0770 and setgid with an operators' group)
        rvis.db                  SQLite, WAL (rvis.db-wal, rvis.db-shm beside it), 0640
        rvis.lock                the running service's lock (flock) and pid
        rvis.sock                the control socket, 0660
        plan.json                the plan `rvis run` reads when --plan is not given
        cell.toml                the cell file `rvis commission` wrote (`rvis run --cell`)
        sensor.toml              the sensor calibration `rvis run` reads when --sensor
                                 is not given (written by `rvis commission`)
        params/current.json      the applied version (derived: rebuilt from the history)
        params/history/NNNN.json every version ever applied (at least four digits: 0007.json,
                                 10000.json; read back by the same rule, ordered by number)
        sweeps/NNNNNNNN.npz      raw sweeps kept for audit ([service] raw_sweeps_keep)
        opcua/server-cert.der    the OPC UA server's certificate (created on first start with
        opcua/server-key.pem     a security policy; the key 0600)
        opcua/trusted/           client certificates the OPC UA server trusts (DER or PEM)
        opcua/rejected/          certificates of clients it refused (move one to trusted/)
        trace/wire.jsonl         the devices' wire trace when on ([devices] trace, `?trace=1`),
                                 rotated to wire.jsonl.1, .2, ... (`rvis devices trace`)
        commission/              `rvis commission`: its journal (journal.json), each step's
                                 results, the report (commission.md, commission.json)
        commission.<time>/       an earlier commissioning kept by `rvis commission --restart`
        verify/                  `rvis sensor verify`: its results
        maintenance/NNNN-<event>/ `rvis maintain`: one procedure's journal, results, report
                                 (maintenance.md, maintenance.json), the files it handed over
        rvis-sim.log             `rvis tui --sim`: the simulated service's log
        simulation.json          the simulated cell a directory `rvis run --sim` made runs
                                 (its seed and measuring path; a commissioned one's cell.toml
                                 says it)

This module is the one place that spells these names (tests/test_layers.py holds every other
module of app/ to it): the service, `rvis state backup|restore|check`, `rvis status`, the TUI
and the commissioning reach them through `StateDir`. What a backup carries besides the
database is `StateDir.carried()`: the parameter history first, then `current.json`, the plan,
the commissioned cell and sensor files, the commissioning's folder and the OPC UA server's
identity (not the lock, the socket, raw sweeps, wire traces or rejected certificates).

Read-only clients (`rvis status`, `rvis ctl`, `rvis tui`, `rvis state check`) only name paths:
nothing here creates, cleans or changes a file unless the caller is the service (`prepare()`,
`follow_group()`, `ServiceLock`) or a writer of the parameters (app/line/params_store.py).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import grp
import json
import os
import shlex
import stat
from dataclasses import dataclass
from pathlib import Path

from app.errors import InputError

DB_NAME = "rvis.db"
SOCKET_NAME = "rvis.sock"
LOCK_NAME = "rvis.lock"
PLAN_NAME = "plan.json"
CELL_NAME = "cell.toml"
SENSOR_NAME = "sensor.toml"
FEATURES_NAME = "features.toml"  # the part type's feature plan (docs/inspection.md)
SIMULATION_NAME = "simulation.json"  # the simulated cell a `rvis run --sim` directory runs
SIM_LOG_NAME = "rvis-sim.log"
PARAMS_DIR = "params"
CURRENT_NAME = "current.json"  # in params/
HISTORY_DIR = "history"  # in params/
SWEEPS_DIR = "sweeps"
OPCUA_DIR = "opcua"
OPCUA_CERT_NAME = "server-cert.der"  # in opcua/
OPCUA_KEY_NAME = "server-key.pem"  # in opcua/, 0600
TRUSTED_DIR = "trusted"  # in opcua/
REJECTED_DIR = "rejected"  # in opcua/
TRACE_DIR = "trace"
WIRE_TRACE_NAME = "wire.jsonl"  # in trace/
COMMISSION_DIR = "commission"
JOURNAL_NAME = "journal.json"  # in commission/: the commissioning's journal
REPORT_MD_NAME = "commission.md"  # in commission/: its report
REPORT_JSON_NAME = "commission.json"
VERIFY_DIR = "verify"
MAINTENANCE_DIR = "maintenance"  # `rvis maintain`: a folder per procedure
MAINTENANCE_REPORT_MD = "maintenance.md"  # in each procedure's folder: its report
MAINTENANCE_REPORT_JSON = "maintenance.json"
#: the manifest `rvis state backup` writes beside the copy (a backup is laid out as a state
#: directory plus this file)
MANIFEST_NAME = "backup.json"


def version_name(version: int) -> str:
    """The name of a parameters version's history file: 0007.json, 10000.json (at least four
    digits, as many as the version has)."""
    return f"{version:04d}.json"


def version_of(name: str) -> int | None:
    """The version a history file's name stands for, by the rule `version_name` writes (None:
    not a version file; "7.json" and "00007.json" are not, "10000.json" is)."""
    stem, dot, ext = name.partition(".")
    if not (dot and ext == "json" and stem.isascii() and stem.isdigit()):
        return None
    version = int(stem)
    return version if version >= 1 and version_name(version) == name else None


#: The state directory when neither the cell file nor `--state-dir` names one ([service]
#: state_dir's default), and the free space [MiB] below which it is low ([service]
#: min_free_mb's default: the `low_disk` alarm, a `rvis state check` problem): app.state_defaults

DIR_MODE, DIR_MODE_GROUP = 0o750, 0o2770  # setgid: new files take the operators' group
UMASK, UMASK_GROUP = 0o027, 0o007  # files 0640 (0660 with the group)
SOCKET_MODE = 0o660


@dataclass(frozen=True)
class StateDir:
    """The paths of one state directory (nothing is created by naming them)."""

    root: Path

    def __init__(self, root: str | Path) -> None:
        object.__setattr__(self, "root", Path(root))

    @property
    def db(self) -> Path:
        return self.root / DB_NAME

    @property
    def socket(self) -> Path:
        return self.root / SOCKET_NAME

    @property
    def lock(self) -> Path:
        return self.root / LOCK_NAME

    @property
    def plan(self) -> Path:
        return self.root / PLAN_NAME

    @property
    def cell(self) -> Path:
        return self.root / CELL_NAME

    @property
    def sensor(self) -> Path:
        return self.root / SENSOR_NAME

    @property
    def params(self) -> Path:
        return self.root / PARAMS_DIR

    @property
    def current(self) -> Path:
        return self.params / CURRENT_NAME

    @property
    def history(self) -> Path:
        return self.params / HISTORY_DIR

    def version_file(self, version: int) -> Path:
        """`params/history/NNNN.json`: the history file of a parameters version."""
        return self.history / version_name(version)

    def versions(self) -> list[int]:
        """The versions in the history, in ascending number (9999 before 10000; reads the
        folder only)."""
        if not self.history.is_dir():
            return []
        found = (version_of(p.name) for p in self.history.iterdir() if p.is_file())
        return sorted(v for v in found if v is not None)

    def stale_temporaries(self) -> list[Path]:
        """Temporary files a crash left before their os.replace (`.NAME.XXXX.tmp` beside the
        parameters): the service removes them; read-only callers never do."""
        folders = (self.params, self.history)
        return [p for d in folders if d.is_dir() for p in d.glob(".*.tmp")]

    @property
    def sweeps(self) -> Path:
        return self.root / SWEEPS_DIR

    @property
    def opcua(self) -> Path:
        return self.root / OPCUA_DIR

    @property
    def opcua_cert(self) -> Path:
        return self.opcua / OPCUA_CERT_NAME

    @property
    def opcua_key(self) -> Path:
        return self.opcua / OPCUA_KEY_NAME

    @property
    def opcua_trusted(self) -> Path:
        return self.opcua / TRUSTED_DIR

    @property
    def opcua_rejected(self) -> Path:
        return self.opcua / REJECTED_DIR

    @property
    def wire_trace(self) -> Path:
        return self.root / TRACE_DIR / WIRE_TRACE_NAME

    @property
    def commission(self) -> Path:
        return self.root / COMMISSION_DIR

    @property
    def commission_report(self) -> Path:
        """`commission/commission.md`: the commissioning's report."""
        return self.commission / REPORT_MD_NAME

    def commission_kept(self, stamp: str) -> Path:
        """`commission.<stamp>`: an earlier commissioning kept by `rvis commission --restart`."""
        return self.root / f"{COMMISSION_DIR}.{stamp}"

    @property
    def verify(self) -> Path:
        return self.root / VERIFY_DIR

    @property
    def maintenance(self) -> Path:
        """`maintenance/`: a folder per `rvis maintain` procedure (`maintenance_folder`)."""
        return self.root / MAINTENANCE_DIR

    def maintenance_folder(self, number: int, event: str) -> Path:
        """`maintenance/NNNN-<event>/` (event: "sensor", "axis3", "fixture")."""
        return self.maintenance / f"{number:04d}-{event}"

    @property
    def sim_log(self) -> Path:
        return self.root / SIM_LOG_NAME

    @property
    def simulation(self) -> Path:
        """The simulated cell (seed, path) of a directory `rvis run --sim` made
        (app/sim/world_record.py)."""
        return self.root / SIMULATION_NAME

    @property
    def features(self) -> Path:
        """The part type's feature plan: with it the service measures the clamped bodies."""
        return self.root / FEATURES_NAME

    @property
    def manifest(self) -> Path:
        """`backup.json`: only in a backup (`rvis state backup`)."""
        return self.root / MANIFEST_NAME

    @property
    def commissioned(self) -> tuple[Path, ...]:
        """The files the commissioning's last step writes for `rvis run` (app/commission/
        ready.py): a directory it commissioned is incomplete without them."""
        return (self.plan, self.cell, self.sensor)

    def carried(self) -> list[Path]:
        """The files, besides the database, that a backup copies and a restore puts back, in
        that order (the history first: a copy holds every version its database names); the
        ones that exist. Private ones (the OPC UA key) are in `private`."""
        tree = [self.commission, self.verify, self.maintenance]
        files = [
            *(self.version_file(v) for v in self.versions()),
            self.current,
            *self.commissioned,
            self.features,
            self.simulation,
            *(p for d in tree if d.is_dir() for p in sorted(d.rglob("*"))),
            self.opcua_cert,
            self.opcua_key,
            *(sorted(self.opcua_trusted.glob("*")) if self.opcua_trusted.is_dir() else []),
        ]
        return [p for p in files if p.is_file() and not p.is_symlink()]

    @property
    def private(self) -> tuple[Path, ...]:
        """Files only the service's user may read (0600 whatever the group)."""
        return (self.opcua_key,)

    def current_version(self) -> int | None:
        """The parameters version `params/current.json` holds (None before the first apply);
        reads only. ValueError, KeyError or TypeError when the file is damaged."""
        if not self.current.is_file():
            return None
        return int(json.loads(self.current.read_text(encoding="utf-8"))["history_version"])

    def free_mb(self) -> float:
        """Free space [MiB] for an unprivileged writer on the directory's file system."""
        st = os.statvfs(self.root if self.root.exists() else self.root.parent)
        return st.f_bavail * st.f_frsize / 2**20


def prepare(state: StateDir, group: str = "") -> None:
    """Create the directory private to the service (0750; with `group`, 0770 setgid owned by
    that group so operators in it can use the socket and read the history), tighten an
    existing one, and set the process umask so every file the service creates is 0640 (0660).
    A directory the service cannot use is an InputError naming it (exit code 2)."""
    gid = _gid(group) if group else None
    mode = DIR_MODE_GROUP if group else DIR_MODE
    try:
        state.root.mkdir(mode=mode, parents=True, exist_ok=True)
        if state.root.stat().st_uid == os.geteuid():
            if gid is not None:
                os.chown(state.root, -1, gid)
            os.chmod(state.root, mode)
        _check_usable(state.root)
    except OSError as exc:
        raise InputError(
            f"cannot use the state directory: {_reason(exc)}", file=state.root
        ) from exc
    os.umask(UMASK_GROUP if group else UMASK)
    for path in (state.db, state.current):  # files of an older, world-readable layout
        with contextlib.suppress(OSError):
            mode_now = stat.S_IMODE(path.stat().st_mode)
            if mode_now & 0o007:
                os.chmod(path, mode_now & ~0o007)


def group_strays(state: StateDir, gid: int) -> list[Path]:
    """What under the directory does not follow the operators' group `gid` as the service
    would have made it with that group: another group, or a folder not 2770 (setgid), a file
    without the group's read and write, or anything open to others; the private files (0600
    whatever the group) and symbolic links excepted. A folder that cannot be read is a stray
    itself (what is inside it is not seen). Reads only."""
    private = set(state.private)
    strays: list[Path] = []
    for top, folders, files in os.walk(state.root, onerror=lambda _exc: None):
        for path in [Path(top)] + [Path(top, f) for f in sorted(files)]:
            with contextlib.suppress(OSError):
                st = path.lstat()
                skip = path in private or stat.S_ISLNK(st.st_mode)
                if not skip and (
                    st.st_gid != gid or _group_mode(st.st_mode) != st.st_mode & 0o7777
                ):
                    strays.append(path)
        folders.sort()
    return strays


def _group_mode(mode: int) -> int:
    """The mode an entry has under an operators' group: a folder 2770, a file with the
    group's read and write (0660), nothing for others."""
    bits = stat.S_IMODE(mode)
    wanted = bits | (0o2070 if stat.S_ISDIR(mode) else 0o060)
    return wanted & ~0o007


def follow_group(state: StateDir, group: str) -> tuple[int, list[Path]]:
    """Give what a directory commissioned (or run) before `[service] operators_group` was set
    the group and its modes (`group_strays`), so operators' TUI history and `rvis state`
    commands work: done by the service at start holding the lock, on what its user may change
    (all of it as root). Returns (how many entries changed, the ones it could not change)."""
    if not group:
        return 0, []
    gid = _gid(group)
    failed: list[Path] = []
    strays = group_strays(state, gid)
    for path in strays:
        try:
            st = path.lstat()
            if st.st_gid != gid:
                os.chown(path, -1, gid, follow_symlinks=False)
            os.chmod(path, _group_mode(st.st_mode))
        except OSError:
            failed.append(path)
    return len(strays) - len(failed), failed


def group_fix_command(state: StateDir, group: str) -> str:
    """The one shell line that does what `follow_group` does, for a person (`rvis state
    check`): group and modes, setgid folders; the private files and links left as they are."""
    root = shlex.quote(str(state.root))
    keep = " ".join(f"! -path {shlex.quote(str(p))}" for p in state.private)
    return (
        f"chgrp -R {shlex.quote(group)} {root} && find {root} ! -type l {keep} -exec chmod"
        f" g+rwX,o-rwx {{}} + && find {root} -type d -exec chmod g+s {{}} +"
    )


def _gid(group: str) -> int:
    try:
        return grp.getgrnam(group).gr_gid
    except KeyError:
        raise InputError(f"no such group {group!r}", field="[service] operators_group") from None


def _check_usable(root: Path) -> None:
    if not root.is_dir():
        raise NotADirectoryError(errno.ENOTDIR, "not a directory", str(root))
    if not os.access(root, os.R_OK | os.W_OK | os.X_OK):
        raise PermissionError(errno.EACCES, "permission denied (needs read, write, search)")


def _reason(exc: OSError) -> str:
    return exc.strerror or str(exc)


class ServiceLock:
    """One service per state directory: an exclusive flock on `rvis.lock` with the holder's
    pid in it, held for the life of the process (the kernel drops it when the process dies,
    however it dies). `acquire()` raises InputError naming the directory and the holder."""

    def __init__(self, state: StateDir) -> None:
        self.state = state
        self._fd: int | None = None

    def acquire(self) -> ServiceLock:
        path = self.state.lock
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o640)
        except OSError as exc:
            raise InputError(f"cannot open the lock: {_reason(exc)}", file=path) from exc
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
            os.close(fd)
            raise InputError(
                f"another rvis service runs on this state directory (pid {holder})",
                file=self.state.root,
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        self._fd = fd
        return self

    def release(self) -> None:
        if self._fd is not None:
            with contextlib.suppress(OSError):
                os.ftruncate(self._fd, 0)
            os.close(self._fd)  # closing drops the flock
            self._fd = None

    def __enter__(self) -> ServiceLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


def holder_pid(state: StateDir) -> int | None:
    """The pid of the service holding the directory's lock, or None when none holds it."""
    try:
        fd = os.open(state.lock, os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            text = os.pread(fd, 32, 0).decode(errors="replace").strip()
            return int(text) if text.isdigit() else -1
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


def disk_usage_mb(root: Path) -> float:
    """Bytes [MiB] of everything under `root`."""
    total = 0
    for dirpath, _dirs, files in os.walk(root):
        for name in files:
            with contextlib.suppress(OSError):
                total += os.lstat(os.path.join(dirpath, name)).st_size
    return total / 2**20


__all__ = [
    "SOCKET_MODE",
    "ServiceLock",
    "StateDir",
    "disk_usage_mb",
    "follow_group",
    "group_fix_command",
    "group_strays",
    "holder_pid",
    "prepare",
    "version_name",
    "version_of",
]
