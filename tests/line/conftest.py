"""Fixtures of the service's tests."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.line.helpers import Line


@pytest.fixture()
def lines() -> Iterator[list[Line]]:
    """The services a test makes (append them): closed after it, whatever happened."""
    made: list[Line] = []
    yield made
    for ln in made:
        ln.close()
