"""Issue 40 item 4 in a real terminal: `rvis tui` (tmux, on its own server socket) attached to
a real `rvis run --cell` whose PLC is unreachable since its start (the simulated line's other
devices up in this process, the PLC's port closed), walked through every pane with the screen
keys at 80x24, then at 120x40. At 80x24 the status line, the alarm banner and each device's
last error show whole; the Overview says the line is unknown; q quits from a table reached by
Tab. With RVIS_TUI_CAPTURES=DIR the screens are written there (docs/tui.md shows them).

The peers are those of tests/ops/test_device_at_start.py (fakes.line.SimLine on a scaled wall
clock, its rendered camera: hence the GigE camera's group)."""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import pytest

from app.commands.cli import main
from app.config import load_cell
from app.sim.cell import make_cell
from app.sim.line_setup import simline_settings
from fakes.line import SimLine
from tests.groups import GIGE_CAMERA
from tests.ports import free_port
from tests.tui.helpers import poll_screen

TMUX = shutil.which("tmux")
RVIS = [sys.executable, "-m", "app"]
CELL = """
[planning]
grid_step_deg = 15.0
[sweep]
n_frames = 12
[line]
window_s = 4.0
margin_s = 0.2
"""
#: a pane's key and a text that only that pane shows
PANES = {
    "overview": ("1", "Line      running"),
    "measurements": ("2", "filter by sphere"),
    "calibrations": ("3", "Parameter versions"),
    "alarms": ("4", "acked by"),
    "devices": ("5", "Last error of each device"),
    "log": ("6", "filter events"),
}
HEADER = re.compile(
    r"fault \(waiting for plc \(unreachable\): next try \S+\) \| window unknown \|"
    r" (no calibration|cal v\d+ .+ old, .+)"
)


@contextlib.contextmanager
def _service_without_plc(tmp_path: Path) -> Iterator[tuple[Path, str]]:
    """`rvis run --cell` on the simulated line's peers, the PLC's port closed: (its state
    directory, the PLC's URL)."""
    base = tmp_path / "base.toml"
    base.write_text(CELL, encoding="utf-8")
    cfg = load_cell(base)
    setup = replace(simline_settings(cfg, geometric=False), warmup=None, clock="scaled", scale=2.0)
    with SimLine(make_cell(cfg, seed=cfg.simulation.seed), setup) as sim:
        urls = {**sim.urls, "plc": f"plc+modbus://127.0.0.1:{free_port()}"}
        devices = "\n".join(f'{k} = "{v}"' for k, v in urls.items())
        cell = tmp_path / "cell.toml"
        cell.write_text(f"{CELL}\n[devices]\n{devices}\n", encoding="utf-8")
        plan = tmp_path / "plan.json"
        assert main(["plan", "--cell", str(cell), "--placement", "fixed", "--out", str(plan)]) == 0
        state = tmp_path / "state"
        argv = [*RVIS, "run", "--cell", str(cell), "--plan", str(plan), "--state-dir", str(state)]
        service = subprocess.Popen(
            argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
        )
        try:
            yield state, urls["plc"]
        finally:
            service.terminate()
            service.wait(60)


class Tmux:
    """A command in a tmux session of its own server: its screen, keys, size."""

    def __init__(self, tmp_path: Path, cmd: str, size: tuple[int, int]) -> None:
        assert TMUX is not None
        w, h = size
        server = f"rvis-test-{os.getpid()}-{tmp_path.name}-{w}x{h}"
        self.tmux = [TMUX, "-L", server, "-f", "/dev/null"]
        self.run("new-session", "-d", "-s", "t", "-x", str(w), "-y", str(h), cmd)

    def run(self, *args: str) -> str:
        out = subprocess.run([*self.tmux, *args], capture_output=True, check=False)
        return out.stdout.decode(errors="replace")

    def screen(self) -> str:
        return self.run("capture-pane", "-p", "-t", "t")

    def keys(self, *keys: str) -> None:
        self.run("send-keys", "-t", "t", *keys)

    def ended(self) -> bool:
        return subprocess.run([*self.tmux, "has-session", "-t", "t"]).returncode != 0

    def kill(self) -> None:
        self.run("kill-server")


def whole(screen: str, text: str) -> bool:
    """The text on the screen whole: on one line or wrapped over lines that follow."""
    flat = " ".join(" ".join(line.split()) for line in screen.splitlines())
    return " ".join(text.split()) in flat


def settled(tmux: Tmux, mark: str, width: int) -> str:
    """The screen once it shows `mark` at the width and is the same twice 0.5 s apart (the
    pane's history drawn: it is read after the pane is shown)."""
    shots = ["", ""]

    def same() -> bool:
        shots[:] = [shots[1], tmux.screen()]
        wide = any(len(line) == width and line[:1] in "━╸╺" for line in shots[1].splitlines())
        return wide and mark in shots[1] and shots[0] == shots[1]

    tick = threading.Event()
    deadline = time.monotonic() + 30.0
    while not same():
        assert time.monotonic() < deadline, shots[1]
        tick.wait(0.5)
    return shots[1]


def walk(tmux: Tmux, size: tuple[int, int], out: Path | None) -> dict[str, str]:
    """Every pane shown with its key; its screen (written to out/<pane>_WxH.txt)."""
    screens = {}
    for pane, (key, mark) in PANES.items():
        tmux.keys(key)
        screens[pane] = settled(tmux, mark, size[0])
        if out is not None:
            (out / f"{pane}_{size[0]}x{size[1]}.txt").write_text(screens[pane])
    return screens


def tui_walk(tmp_path: Path, state: Path, size: tuple[int, int]) -> dict[str, str]:
    """`rvis tui` in a terminal of that size, once it shows the fault: every pane's screen;
    then q, from a table reached by Tab, quits."""
    captures = os.environ.get("RVIS_TUI_CAPTURES")
    # COLUMNS and LINES unset: this tmux hands its panes COLUMNS=80 LINES=24 (seen in a
    # 120x40 pane started from the test), and a terminal that has them takes them as its size
    cmd = f"env -u COLUMNS -u LINES {' '.join(RVIS)} tui --state-dir {state}"
    tmux = Tmux(tmp_path, cmd, size)
    try:
        assert poll_screen(lambda: tmux.screen().lstrip().startswith("fault"), 60.0), tmux.screen()
        assert poll_screen(lambda: "ALARM URGENT" in tmux.screen(), 30.0), tmux.screen()
        screens = walk(tmux, size, Path(captures) if captures else None)
        tmux.keys("3", "Tab", "Tab", "q")
        assert poll_screen(tmux.ended, 30.0), tmux.screen()
        return screens
    finally:
        tmux.kill()


@GIGE_CAMERA
@pytest.mark.slow  # a service in its own process and the line's peers: ~30 s
@pytest.mark.skipif(TMUX is None, reason="tmux not installed")
def test_the_tui_in_a_fault_at_80x24_and_120x40(tmp_path: Path) -> None:
    with _service_without_plc(tmp_path) as (state, plc_url):
        screens = tui_walk(tmp_path, state, (80, 24))
        for pane, screen in screens.items():
            lines = [k.strip() for k in screen.splitlines()]
            banner = lines.index(next(k for k in lines if k.startswith("ALARM URGENT")))
            assert HEADER.fullmatch(" ".join(lines[:banner])), (pane, screen)
            assert whole(screen, f"plc ({plc_url}) unreachable: DeviceConnectionError"), pane
            assert whole(screen, "and leaves FAULT by itself once every device answers")
        devices = screens["devices"]
        assert re.search(r"^ plc +UNREACHABLE", devices, re.M), devices
        error = f"DeviceConnectionError: {plc_url.split('//')[1]}: cannot connect"
        assert whole(devices, error), devices
        line = next(k for k in screens["overview"].splitlines() if k.strip().startswith("Line"))
        assert "running unknown, PLC heartbeat unknown" in line, screens["overview"]
        tui_walk(tmp_path, state, (120, 40))
