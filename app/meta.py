"""Provenance of what rvis writes: its version, the git commit of the code when it runs from a
checkout, the seed, the UTC time and the command line."""

from __future__ import annotations

import functools
import shlex
import subprocess
import sys
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from typing import Any


def version() -> str:
    try:
        return metadata.version("rvis")
    except metadata.PackageNotFoundError:
        return "unknown"


@functools.cache
def software_revision() -> str:
    """The version and, from a checkout, its commit: what `rvis --version` prints after
    "rvis " (also the OPC UA Identification's SoftwareRevision)."""
    commit = git_commit()
    return version() + (f" ({commit})" if commit else "")


def git_commit() -> str | None:
    """The commit of the checkout rvis runs from (with '+dirty' when changed), or None."""
    root = Path(__file__).resolve().parent.parent
    if not (root / ".git").exists():
        return None
    try:
        out = subprocess.run(
            ["git", "-C", str(root), "describe", "--always", "--dirty=+dirty", "--abbrev=12"],
            capture_output=True,
            text=True,
            timeout=5,
            check=True,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None


def provenance(seed: int | None = None) -> dict[str, Any]:
    """A JSON-ready record of who wrote a file, when, and from what command."""
    return {
        "rvis_version": version(),
        "git_commit": git_commit(),
        "seed": seed,
        "utc_time": datetime.now(UTC).isoformat(timespec="seconds"),
        "command_line": shlex.join(["rvis", *sys.argv[1:]]),
    }
