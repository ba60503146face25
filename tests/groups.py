"""Which tests must share one pytest-xdist worker (`scripts/test` runs `--dist loadgroup`).

GIGE_CAMERA: the tests that start Aravis's GigE Vision fake camera (fakes/gv_camera.py), in
this process or in an `rvis` they start (`SimulatedLineRun(geometric=False)`, `SimLine` with its
camera, `rvis commission --sim`, `rvis sensor verify --sim`, `rvis devices check`). There is one
fake per address in a network namespace: a second one waits for the lock of the address until
the first closes. Each worker normally runs in a network namespace of its own (tests/netns.py),
and then these tests spread over the workers like any other. Where a worker cannot have one (no
CAP_SYS_ADMIN), tests/conftest.py puts them in one xdist group: on one worker they take turns
without the other worker's test standing idle in that wait (its wall-clock bounds and its
timeout running meanwhile).

The tests of a module- or package-scoped fixture are grouped by tests/conftest.py itself (the
fixture is built once, not once per worker); a test marked here keeps only this mark's group.
"""

from __future__ import annotations

import pytest

GIGE_CAMERA = pytest.mark.gige_camera
