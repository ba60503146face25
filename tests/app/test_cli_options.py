"""Options before or after the verb: an option of a command with verbs (`rvis ctl`, `rvis state`,
...) applies to each of its verbs and is read the same wherever it stands, `rvis ctl pause
--state-dir S` (the README's order) as `rvis ctl --state-dir S pause`."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from app.commands import COMMANDS
from app.commands.cli import build_parser
from tests.app.conftest import Cli


def _verbs(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _command(name: str) -> argparse.ArgumentParser:
    return _verbs(build_parser([name]))[name]


def _value(action: argparse.Action) -> list[str]:
    """Words that give `action` a value other than its default."""
    if action.nargs == 0:
        return []
    return [str(list(action.choices)[-1]) if action.choices else "1"]


def _required_words(verb: argparse.ArgumentParser) -> list[str]:
    """The verb's positionals and required options, each with a value."""
    words: list[str] = []
    for action in verb._actions:
        if not action.option_strings and not isinstance(action, argparse._SubParsersAction):
            words += _value(action)
        elif action.required:
            words += [action.option_strings[0], *_value(action)]
    return words


def _shared(command: argparse.ArgumentParser) -> list[argparse.Action]:
    return [a for a in command._actions if a.option_strings and a.dest != "help"]


WITH_VERBS = sorted(name for name in COMMANDS if _verbs(_command(name)))


def test_the_commands_with_verbs_are_found() -> None:
    assert {"ctl", "state", "devices", "experiment", "sensor"} <= set(WITH_VERBS)


@pytest.mark.parametrize("name", WITH_VERBS)
def test_every_shared_option_parses_the_same_before_or_after_each_verb(name: str) -> None:
    command = _command(name)
    shared = _shared(command)
    assert shared, f"rvis {name}: no option of the command (at least --log-level)"
    for verb_name, verb in _verbs(command).items():
        tail = _required_words(verb)
        for action in shared:
            given = [action.option_strings[0], *_value(action)]
            root = build_parser([name])
            before = root.parse_args([name, *given, verb_name, *tail])
            after = root.parse_args([name, verb_name, *tail, *given])
            where = f"rvis {name} {verb_name} {' '.join(given)}"
            assert vars(before) == vars(after), where
            default = root.parse_args([name, verb_name, *tail])
            assert getattr(before, action.dest) != getattr(default, action.dest), where


def test_every_shared_option_together_on_both_sides() -> None:
    """All of ctl's options before the verb, or all after it: one namespace."""
    root = build_parser(["ctl"])
    opts = ["--cell", "c.toml", "--state-dir", "S", "--json", "--log-level", "debug"]
    before = root.parse_args(["ctl", *opts, "shelve", "7", "dusty", "--minutes", "5"])
    after = root.parse_args(["ctl", "shelve", "7", "dusty", "--minutes", "5", *opts])
    assert vars(before) == vars(after)
    assert (before.state_dir, before.cell, before.json) == ("S", "c.toml", True)
    assert (before.alarm, before.reason, before.minutes) == (7, "dusty", 5.0)


@pytest.mark.parametrize(
    ("argv", "code", "says"),
    [
        (["ctl", "pause", "--state-dir", "{s}"], 1, "no service is running at {s}/rvis.sock"),
        (["ctl", "--state-dir", "{s}", "pause"], 1, "no service is running at {s}/rvis.sock"),
        (["ctl", "ack", "3", "--state-dir", "{s}"], 1, "no service is running at {s}/rvis.sock"),
        (["status", "--state-dir", "{s}"], 2, "{s}: no service state here"),
    ],
)
def test_ctl_in_the_readmes_order_reaches_the_state_directory(
    argv: list[str], code: int, says: str, tmp_path: Path, cli: Cli
) -> None:
    got, _, err = cli([w.format(s=tmp_path) for w in argv])
    (line,) = err.strip().splitlines()
    assert got == code and says.format(s=tmp_path) in line  # the directory given, wherever it stood


@pytest.mark.parametrize(
    "argv", [["state", "--state-dir", "{s}", "check"], ["state", "check", "--state-dir", "{s}"]]
)
def test_state_check_with_the_state_dir_before_or_after_the_verb(
    argv: list[str], tmp_path: Path, cli: Cli
) -> None:
    state = tmp_path / "state"
    state.mkdir(mode=0o750)
    code, out, err = cli([w.format(s=state) for w in argv])
    assert "unrecognized" not in err and "required" not in err
    assert code == 1 and f"state directory  {state}" in out  # no database: a finding
