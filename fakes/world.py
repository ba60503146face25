"""What the device fakes need from a simulated world, and a tiny world for driver tests.

The fakes (fake:// backends and the protocol peers) move *the simulated cell's robot* and measure
*the simulated cell's spheres* through this Protocol only, so the simulated cell
(``fakes/cell.py``, with its own true kinematics and renderer) can implement it without the fakes
knowing its internals.

Contract (all methods may be called from a peer's background thread; implementations must be
thread-safe for these calls):

- ``set_joints_deg(q_deg)``: the robot's joints are now ``q_deg`` (controller angles J1..J6 [deg],
  shape (6,)). Fakes call it along the motion path (interpolated), not only at the end.
- ``joints_deg()``: the robot's current controller joint angles [deg], shape (6,), a copy.
- ``target_ids()``: the ids of the fixed targets (spheres), e.g. ``["S1", "S2", "S3", "S4"]``.
- ``target_true_mm(target_id)``: the target's true centre [mm] in the part frame, shape (3,);
  KeyError for an unknown id. The fake tracker adds its own noise.
- ``render_frame(width, height, exposure_us, gain_db, galvo_v)``: the image the camera sees
  now, shape (height, width), float64 in [0, 1] (the fake camera quantises it to the pixel
  format). ``galvo_v`` is the galvo command in DAC volts (None when no galvo is attached); the
  world's true sensor turns it into the mirror angle with its own model.
- ``render_counts(...)`` (optional, same arguments): a world that renders integer digital
  numbers gives them as they are, with their full scale: ``(counts, full_scale)``, the frame
  being ``counts / full_scale``. The fake cameras quantise through `frame_in_format`, which
  maps such counts through a table: the same numbers as from ``render_frame``, without a
  floating-point frame in between (1.25 million pixels a frame).
"""

from __future__ import annotations

import threading
from collections.abc import Mapping, Sequence
from functools import lru_cache
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


@runtime_checkable
class World(Protocol):
    def set_joints_deg(self, q_deg: ArrayLike) -> None: ...

    def joints_deg(self) -> FloatArray: ...

    def target_ids(self) -> list[str]: ...

    def target_true_mm(self, target_id: str) -> FloatArray: ...

    def render_frame(
        self, width: int, height: int, exposure_us: float, gain_db: float, galvo_v: float | None
    ) -> FloatArray: ...


def frame_in_format(
    world: World,
    size_wh: tuple[int, int],
    exposure_us: float,
    gain_db: float,
    galvo_v: float | None,
    top: int,
) -> NDArray[Any]:
    """The world's frame of size_wh (width, height) quantised to a camera's pixel format of
    maximum value `top` (255: uint8, else uint16): round(clip(frame, 0, 1) * top). Through the
    world's `render_counts` and a table where it has it (module docstring)."""
    dtype = np.dtype(np.uint8) if top == 255 else np.dtype("<u2")
    counts = getattr(world, "render_counts", None)
    if counts is not None:
        dn, full_scale = counts(*size_wh, exposure_us, gain_db, galvo_v)
        return np.take(_count_table(int(full_scale), top, dtype.str), dn)
    frame = world.render_frame(*size_wh, exposure_us, gain_db, galvo_v)
    return np.round(np.clip(frame, 0.0, 1.0) * top).astype(dtype)


@lru_cache(maxsize=8)
def _count_table(full_scale: int, top: int, dtype: str) -> NDArray[Any]:
    """round(clip(n / full_scale, 0, 1) * top) for every count n: the frame's values as the
    camera quantises them (the same division as the floating-point frame's)."""
    n = np.arange(full_scale + 1, dtype=np.float64)
    table = np.round(np.clip(n / float(full_scale), 0.0, 1.0) * top).astype(dtype)
    table.flags.writeable = False
    return table


class StaticWorld:
    """Joints stored, targets given; frames are a gradient with a bright line at a column
    proportional to the galvo command (-10 V left edge, +10 V right edge).

    ``StaticWorld({"S1": (1000, 0, -300)}, q_deg=(0, 0, 0, 0, -90, 0))``.
    """

    def __init__(
        self,
        targets_mm: Mapping[str, Sequence[float]] | None = None,
        q_deg: Sequence[float] = (0.0, 0.0, 0.0, 0.0, -90.0, 0.0),
    ) -> None:
        default = {
            "S1": (1072.73, 1394.23, -288.43),
            "S2": (-823.53, 806.94, -261.44),
            "S3": (-1207.93, -1377.56, 101.86),
            "S4": (946.27, -1043.51, 682.61),
        }
        self._targets = {
            k: np.asarray(v, dtype=np.float64).reshape(3)
            for k, v in (targets_mm or default).items()
        }
        self._q = np.asarray(q_deg, dtype=np.float64).reshape(6)
        self._lock = threading.Lock()
        self.moves = 0  # number of set_joints_deg calls, for tests

    def set_joints_deg(self, q_deg: ArrayLike) -> None:
        q = np.asarray(q_deg, dtype=np.float64).reshape(6)
        with self._lock:
            self._q = q.copy()
            self.moves += 1

    def joints_deg(self) -> FloatArray:
        with self._lock:
            return self._q.copy()

    def target_ids(self) -> list[str]:
        return list(self._targets)

    def target_true_mm(self, target_id: str) -> FloatArray:
        return self._targets[target_id].copy()

    def render_frame(
        self, width: int, height: int, exposure_us: float, gain_db: float, galvo_v: float | None
    ) -> FloatArray:
        gain = exposure_us / 10_000.0 * 10 ** (gain_db / 20.0)
        ramp = np.linspace(0.05, 0.25, width)[None, :].repeat(height, axis=0)
        if galvo_v is not None:
            col = round((galvo_v + 10.0) / 20.0 * (width - 1))
            ramp[:, max(col - 1, 0) : col + 2] = 0.9
        return np.clip(ramp * gain, 0.0, 1.0)
