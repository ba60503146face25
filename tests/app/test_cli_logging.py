"""The command line's logging is chosen, not Python's last resort: a batch run with alarms prints
no log record on stderr (the alarms are in its summary); `--log-level` prints the records as
text lines on stderr, the event's data included; the option is accepted before and after the
command and checked."""

from __future__ import annotations

import json
import logging
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from app.commands.cli import main
from app.commands.logs import configure
from tests.app.conftest import Cli

ROOT = Path(__file__).resolve().parents[2]

#: A simulated line that raises a step alarm within a few windows: a large knock of the sensor
#: mount in its third clamp cycle, found by the estimator from the next measurement on.
ALARM_CELL = """\
[simline]
scale = 600.0
knock_at_s = 150.0
knock_mm = 2.0
knock_deg = 0.5
[line]
slots_per_window = 2
"""


@pytest.fixture(autouse=True)
def _cli_handler_removed() -> Iterator[None]:
    yield
    configure("off")  # this process's `rvis` logger as main() leaves it by default


def test_a_batch_run_with_alarms_leaves_stderr_clean(tmp_path: Path) -> None:
    """In a fresh process (no handler anywhere, as a user's shell): before the fix, each alarm
    and each robot abort was a bare line on stderr ("alarm", "rmi://...: abort")."""
    cell = tmp_path / "cell.toml"
    cell.write_text(ALARM_CELL)
    argv = ["run", "--sim", "--geometric", "--windows", "6", "--cell", str(cell)]
    argv += ["--state-dir", str(tmp_path / "state")]
    done = subprocess.run(
        [sys.executable, "-m", "app", *argv],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    last = json.loads(done.stdout.strip().splitlines()[-1])  # stdout: JSON lines only
    assert last["event"] == "sim_summary"
    assert any(a.startswith("step of") for a in last["data"]["alarms"]), last["data"]
    started, summary = done.stderr.splitlines()  # stderr: the words for a person, no record
    assert started.startswith("rvis run --sim: seed")
    assert re.search(r"alarms [1-9]\d*: step of", summary), summary


def test_log_level_prints_records_with_their_data_on_stderr(
    capsys: pytest.CaptureFixture[str],
) -> None:
    configure("warning")
    log = logging.getLogger("rvis.line")
    log.warning("alarm", extra={"event": "alarm", "data": {"code": "drift", "message": "knock"}})
    log.info("window", extra={"event": "window", "data": {"n": 3}})
    err = capsys.readouterr().err
    assert err == 'WARNING rvis.line: alarm {"code": "drift", "message": "knock"}\n'
    configure("off")
    log.warning("alarm")
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize(
    "argv",
    [
        ["--log-level", "info", "observability", "--measurements", "MISSING"],
        ["observability", "--measurements", "MISSING", "--log-level", "info"],
    ],
)
def test_log_level_before_or_after_the_command(argv: list[str], tmp_path: Path, cli: Cli) -> None:
    missing = str(tmp_path / "missing.csv")  # the command stops at once (exit 2), logging set
    code, _, err = cli([missing if a == "MISSING" else a for a in argv])
    assert code == 2 and "missing.csv" in err
    handlers = logging.getLogger("rvis").handlers
    assert [h.level for h in handlers if getattr(h, "_rvis_cli_handler", False)] == [logging.INFO]


def test_bad_log_level_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(["--log-level", "loud", "simulate", "--out", "x"])
    assert exit_.value.code == 2
    assert "--log-level" in capsys.readouterr().err
