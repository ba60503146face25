"""Shared fixtures: the default cell and simulated data sets (seeded, cached per session), and how
the tests are shared out between pytest-xdist's workers (`scripts/test` runs `-n 5 --dist
loadgroup` on 2 cores; a session fixture is built once per worker, a worker being a process of its
own, in a network namespace of its own where it may: tests/netns.py)."""

from __future__ import annotations

from app.threads import limit_blas_threads

limit_blas_threads()  # as the rvis entry point does, before numpy loads

from collections.abc import Generator  # noqa: E402
from functools import cache  # noqa: E402
from typing import Any  # noqa: E402

import pytest  # noqa: E402

from app.config import CellConfig, load_cell  # noqa: E402
from app.sim.cell import DataSet, simulated_sets  # noqa: E402
from fakes.wiring import register_fakes  # noqa: E402
from tests.netns import enter_own_network_namespace  # noqa: E402

#: why this worker shares the host's network namespace (None: it has one of its own)
_SHARED_NETWORK = pytest.StashKey[str | None]()


def pytest_configure(config: pytest.Config) -> None:
    """A pytest-xdist worker enters a network namespace of its own (tests/netns.py) before any
    test runs: its loopback servers cannot meet the other worker's."""
    if hasattr(config, "workerinput"):
        config.stash[_SHARED_NETWORK] = enter_own_network_namespace()


@pytest.fixture(scope="session", autouse=True)
def _fakes_wired() -> None:
    """fake:// opens the simulated cell's devices, as the application wires them."""
    register_fakes()


@pytest.fixture(scope="session")
def cfg() -> CellConfig:
    return load_cell(None)


@cache
def simulated(seed: int, n_validation: int = 60, **overrides: bool) -> tuple[DataSet, DataSet]:
    """(calibration set of 4 x 6, validation set) of the simulated cell."""
    sim = simulated_sets(load_cell(None), seed, n_each=6, n_validation=n_validation, **overrides)  # type: ignore[arg-type]
    return sim.calibration, sim.validation


#: fixture scopes whose value the tests of a module or package share: such tests go to one worker
_SHARED_SCOPES = ("class", "module", "package")


def _shared_fixture_group(item: pytest.Item) -> str | None:
    """The xdist group of a test that uses a class-, module- or package-scoped fixture: its
    module, or the fixture's package (built once on one worker, not once on each)."""
    info: Any = getattr(item, "_fixtureinfo", None)
    if info is None:
        return None
    for name in info.names_closure:
        defs = info.name2fixturedefs.get(name)
        if defs and defs[-1].scope in _SHARED_SCOPES:
            if defs[-1].scope == "package":
                return defs[-1].baseid or "."
            return item.nodeid.split("::")[0]
    return None


def _group_names(item: pytest.Item) -> list[str]:
    names = {
        str(m.args[0] if m.args else m.kwargs.get("name", "default"))
        for m in item.iter_markers("xdist_group")
    }
    return sorted(names)


def _suffix_groups(items: list[pytest.Item]) -> None:
    """What pytest-xdist 3.8's loadgroup does, for pytest >= 9.2: the group name appended to
    the node id ("...::test@group"), which is how the scheduler learns it. xdist still writes
    the node id of pytest < 9.2 (`_nodeid`), which pytest 9.2 no longer reads (its node id is
    structured, `_id`): every group would silently be ignored (pytest-xdist issue 1386). A
    no-op where xdist's own suffix took effect."""
    for item in items:
        names = _group_names(item)
        nodeid = item.nodeid
        if not names or nodeid.rfind("@") > nodeid.rfind("]"):
            continue
        from _pytest.nodeid import NodeId

        item._id = NodeId.parse(f"{nodeid}@{'_'.join(names)}")


@pytest.hookimpl(wrapper=True)
def pytest_collection_modifyitems(
    config: pytest.Config, items: list[pytest.Item]
) -> Generator[None, None, None]:
    """On a pytest-xdist worker: the tests of a shared fixture grouped (tests/groups.py), the
    GigE camera's tests in one group unless the worker has a network namespace of its own, and
    the tests marked slow first, so that no worker starts one at the end while the other has
    finished (xdist hands tests out in collection order). A serial run keeps the file order."""
    worker = hasattr(config, "workerinput")
    if worker:
        one_camera = config.stash.get(_SHARED_NETWORK, None) is not None
        for item in items:
            if one_camera and item.get_closest_marker("gige_camera") is not None:
                item.add_marker(pytest.mark.xdist_group("gige-camera"))
            elif item.get_closest_marker("xdist_group") is None:
                group = _shared_fixture_group(item)
                if group is not None:
                    item.add_marker(pytest.mark.xdist_group(group))
        items.sort(key=lambda item: item.get_closest_marker("slow") is None)
    yield  # the other plugins', xdist's among them
    if worker and config.getvalue("loadgroup"):
        _suffix_groups(items)
