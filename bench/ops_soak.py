"""Soak of the service as the plant runs it (issue 19, "must show"): `rvis run --sim --geometric
--windows N` as its own process on a fast simulated clock (the service's defaults: one slot per
window, a recalibration every 24 measurements), sampled from outside every 100 windows: resident
memory, open file descriptors and threads of the process, and the state directory's bytes (the
database with its WAL, the parameter history) with each table's share. They must stay flat: the
same growth for every 100 windows, no leak.

    nice -n 5 .venv/bin/python bench/ops_soak.py [--windows 1000] [--every 100]
"""

from __future__ import annotations

import argparse
import sqlite3
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.line.statedir import StateDir, disk_usage_mb
from tests.ops.conftest import ServiceProcess

CELL = "[simline]\nscale = 300.0\n"


def proc_figures(pid: int) -> tuple[float, int, int]:
    """(RSS MiB, open fds, threads) of process `pid`, its worker processes not included."""
    status = Path(f"/proc/{pid}/status").read_text().splitlines()
    fields = dict(line.split(":", 1) for line in status if ":" in line)
    fds = len(list(Path(f"/proc/{pid}/fd").iterdir()))
    return int(fields["VmRSS"].split()[0]) / 1024, fds, int(fields["Threads"])


def table_bytes(db: Path) -> dict[str, int]:
    """Each table's bytes with its indexes, and the whole database as `*` (its logical size:
    the pages in the file and in the WAL, as a reader sees them)."""
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        owner = dict(con.execute("SELECT name, tbl_name FROM sqlite_schema").fetchall())
        out: dict[str, int] = {}
        for name, n in con.execute("SELECT name, SUM(pgsize) FROM dbstat GROUP BY name"):
            table = owner.get(name, name)
            out[table] = out.get(table, 0) + int(n)
        page_count = con.execute("PRAGMA page_count").fetchone()[0]
        out["*"] = int(page_count) * int(con.execute("PRAGMA page_size").fetchone()[0])
        return out
    finally:
        con.close()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--windows", type=int, default=1000)
    p.add_argument("--every", type=int, default=100)
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        cell = Path(tmp) / "cell.toml"
        cell.write_text(CELL, encoding="utf-8")
        paths = StateDir(Path(tmp) / "state")
        svc = ServiceProcess(paths.root, cell)
        print(
            "windows  rss_MiB  fds  threads  db_KiB  wal_KiB  params_KiB  +KiB"
            "  measurements  calibrations  events  service_state"
        )
        t0, last_kib, n = time.monotonic(), 0.0, 0
        rows = []
        try:
            svc.wait_ready()
            n = 1
            while n < args.windows:
                svc.wait_windows(1, 60.0)
                n += 1
                if n % args.every:
                    continue
                rss, fds, threads = proc_figures(svc.proc.pid)
                sizes = table_bytes(paths.db)
                wal = paths.db.with_name(paths.db.name + "-wal")
                db_kib = sizes["*"] / 1024
                params_kib = disk_usage_mb(paths.params) * 1024
                kept_kib = db_kib + params_kib  # the WAL file is reused: not counted
                rows.append(
                    f"{n:7d}  {rss:7.1f}  {fds:3d}  {threads:7d}  {db_kib:6.0f}"
                    f"  {wal.stat().st_size / 1024 if wal.exists() else 0:7.0f}  {params_kib:10.0f}"
                    f"  {kept_kib - last_kib:8.0f}"
                    f"  {sizes.get('measurements', 0) / 1024:12.0f}"
                    f"  {sizes.get('calibrations', 0) / 1024:12.0f}"
                    f"  {sizes.get('events', 0) / 1024:6.0f}"
                    f"  {sizes.get('service_state', 0) / 1024:13.0f}"
                )
                print(rows[-1], flush=True)
                last_kib = kept_kib
        finally:
            code = svc.stop()
        print(f"{n} windows in {time.monotonic() - t0:.0f} s wall; the service exited {code}")
    return 0 if code == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
