"""The README's command table and cell-section list agree with the parsers and the loader:
every command and experiment has a row, every flag a row names exists, every flag a parser
has is named in its command's rows, and the section list is the loader's."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from app.commands import COMMANDS
from app.commands.cli import build_parser, command_parsers
from app.config import SECTIONS

README = Path(__file__).resolve().parents[2] / "README.md"
NOT_LISTED = {"-h", "--help", "--log-level", "--version"}


def _table_rows() -> list[str]:
    """The first cells of the rows of the table under '## The command line'."""
    text = README.read_text(encoding="utf-8")
    part = text.split("## The command line", 1)[1].split("\n## ", 1)[0]
    return [line.split(" | ", 1)[0] for line in part.splitlines() if line.startswith("| `rvis")]


def _invocations(cell: str) -> list[tuple[str, list[str]]]:
    """(command, [sub-command words]) of every `rvis ...` in a row's first cell."""
    out = []
    for m in re.finditer(r"`rvis ([a-z-]+)((?: [a-z][a-z-]*(?:\\\|[a-z][a-z-]*)*)*)", cell):
        words = re.split(r"[ \\|]+", m.group(2).strip()) if m.group(2).strip() else []
        out.append((m.group(1), [w for w in words if w]))
    return out


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _flags(parser: argparse.ArgumentParser) -> set[str]:
    return {
        s
        for p in command_parsers(parser)
        for a in p._actions
        for s in a.option_strings
        if s.startswith("--") and s not in NOT_LISTED
    }


def _command_parser(name: str) -> argparse.ArgumentParser:
    root = build_parser([name])
    return _subcommands(root)[name]


def _rows_by_command() -> dict[str, list[str]]:
    """Per command, the parts of the rows that invoke it (from its `rvis` to the next one)."""
    rows: dict[str, list[str]] = {}
    for cell in _table_rows():
        parts = cell.split("`rvis ")[1:]
        for part in parts:
            command = re.match(r"[a-z-]+", part)
            assert command is not None, part
            rows.setdefault(command.group(0), []).append(part)
    return rows


def test_every_command_has_a_row_and_every_experiment_too() -> None:
    rows = _rows_by_command()
    assert sorted(rows) == sorted(COMMANDS)
    named = {w[0] for cell in _table_rows() for c, w in _invocations(cell) if c == "experiment"}
    assert named == set(_subcommands(_command_parser("experiment")))


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_the_rows_flags_are_the_parsers(command: str) -> None:
    """A flag in a command's rows exists in its parser (or one of its sub-commands'), and every
    flag its parsers have is in its rows."""
    parser = _command_parser(command)
    text = " ".join(_rows_by_command()[command])
    named = set(re.findall(r"(?<![\w-])--[a-z][a-z0-9-]*", text))
    have = _flags(parser)
    assert named - have == set(), f"rvis {command}: README names flags it does not have"
    assert have - named == set(), f"rvis {command}: flags missing from the README's table"


def test_the_cell_sections_listed_are_the_loaders() -> None:
    text = README.read_text(encoding="utf-8")
    m = re.search(r"the sections and keys,.*?\((`[a-z_]+`(?:,\s+`[a-z_]+`)*)\)", text, re.S)
    assert m is not None, "the README's list of cell sections"
    listed = re.findall(r"`([a-z_]+)`", m.group(1))
    assert listed == [s.name for s in SECTIONS]
