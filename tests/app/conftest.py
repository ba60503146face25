"""Fixtures of the command-line tests: a simulated data set on disk and a runner of `rvis`."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from app.commands.cli import main

Cli = Callable[[list[str]], tuple[int, str, str]]


@pytest.fixture(scope="session")
def simdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """`rvis simulate --seed 4 --validation 40` written once."""
    out = tmp_path_factory.mktemp("sim")
    assert main(["simulate", "--out", str(out), "--seed", "4", "--validation", "40"]) == 0
    return out


@pytest.fixture()
def cli(capsys: pytest.CaptureFixture[str]) -> Cli:
    """Runs `rvis ARGV` in this process: (exit code, stdout, stderr); never a traceback."""

    def run(argv: list[str]) -> tuple[int, str, str]:
        code = main(argv)
        cap = capsys.readouterr()
        assert "Traceback" not in cap.err
        return code, cap.out, cap.err

    return run
