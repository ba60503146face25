"""`rvis tui --sim` in a real pseudo-terminal (tmux, on its own server socket; Textual draws on
stderr, so it is not redirected): the rendered
screen shows the simulated service's state and, on the Bodies pane, the bodies it measures, and q
quits, stopping that service."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from app.line.statedir import StateDir
from tests.tui.helpers import poll_screen

TMUX = shutil.which("tmux")
RVIS = Path(sys.executable).with_name("rvis")


def _listening(path: Path) -> bool:
    with socket.socket(socket.AF_UNIX) as s:
        try:
            s.connect(str(path))
        except OSError:
            return False
    return True


@pytest.mark.skipif(TMUX is None, reason="tmux not installed")
def test_tui_sim_in_a_terminal_shows_the_service_and_quits(tmp_path: Path) -> None:
    assert TMUX is not None
    tmux = [TMUX, "-L", f"rvis-test-{os.getpid()}-{tmp_path.name}", "-f", "/dev/null"]
    cmd = f"{RVIS} tui --sim --state-dir {tmp_path}"
    subprocess.run(
        [*tmux, "new-session", "-d", "-s", "t", "-x", "100", "-y", "30", cmd], check=True
    )
    try:

        def screen() -> str:
            out = subprocess.run([*tmux, "capture-pane", "-p", "-t", "t"], capture_output=True)
            return out.stdout.decode(errors="replace")

        def attached() -> bool:
            first = screen().split("\n", 1)[0].strip()
            return first.split(" ", 1)[0] in ("idle", "measuring", "paused", "starting")

        assert poll_screen(attached, 30.0), screen()
        assert "Overview" in screen()
        assert (tmp_path / "rvis.sock").exists()
        # the simulated line measures the simulated part type's bodies: the Bodies pane (7)
        assert StateDir(tmp_path).features.is_file()
        subprocess.run([*tmux, "send-keys", "-t", "t", "7"], check=True)
        assert poll_screen(lambda: "charact." in screen() and "\nBody " in screen(), 60.0), screen()
        subprocess.run([*tmux, "send-keys", "-t", "t", "q"], check=True)

        def ended() -> bool:
            return (
                subprocess.run([*tmux, "has-session", "-t", "t"], capture_output=True).returncode
                != 0
            )

        assert poll_screen(ended, 30.0), screen()
        assert not _listening(tmp_path / "rvis.sock")  # the simulated service stopped with it
    finally:
        subprocess.run([*tmux, "kill-server"], capture_output=True)
