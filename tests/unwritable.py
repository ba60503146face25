"""A folder made unwritable for a while, for tests of what rvis does when it cannot write.

`chmod 0o500` does it for an ordinary user; root passes over modes (CAP_DAC_OVERRIDE), and the
test command runs as root on a fresh machine (README), so as root the folder is also made
immutable (`chattr +i`, which binds root too). A test skips when neither binds here (a file
system without the attribute, no chattr). Both are undone on leaving, whatever happened."""

from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest


def _chattr(flag: str, folder: Path) -> bool:
    tool = shutil.which("chattr")
    if tool is None:
        return False
    return subprocess.run([tool, flag, str(folder)], capture_output=True).returncode == 0


def _binds(folder: Path) -> bool:
    probe = folder / ".probe"
    try:
        probe.write_bytes(b"")
    except OSError:
        return True
    probe.unlink()
    return False


@contextmanager
def unwritable(folder: Path) -> Iterator[None]:
    """`folder` (which exists) unwritable inside the block, its mode given back after."""
    mode = folder.stat().st_mode & 0o7777
    immutable = False
    folder.chmod(0o500)
    try:
        if os.geteuid() == 0:
            immutable = _chattr("+i", folder)
        if not _binds(folder):
            pytest.skip(f"{folder}: cannot be made unwritable here (root, no immutable flag)")
        yield
    finally:
        if immutable:
            _chattr("-i", folder)
        folder.chmod(mode)
