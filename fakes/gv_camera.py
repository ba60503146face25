"""Aravis's own GigE Vision fake camera on 127.0.0.1, serving frames rendered from a World.

``Aravis.GvFakeCamera`` runs in-process and answers a normal Aravis client over real UDP on
loopback (GVCP port 3956: one fake per address). Its image content comes from a fill callback
registered through ctypes (``arv_fake_camera_set_fill_pattern``): a PyGObject callback would be
freed too early and crash. The callback renders ``world.render_frame`` at the requested region
size (offsets are not passed to the callback) and quantises it to the pixel format.

    with GvCamera(world) as gv:
        camera = AravisCamera(gv.camera_id)     # "127.0.0.1"
"""

from __future__ import annotations

import ctypes
from typing import Any, Self

import numpy as np

from fakes.world import World

_FILL = ctypes.CFUNCTYPE(
    None, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint32, ctypes.c_uint32, ctypes.c_uint32
)


def _aravis() -> tuple[Any, ctypes.CDLL]:
    import gi

    gi.require_version("Aravis", "0.8")
    from gi.repository import Aravis

    lib = ctypes.CDLL("libaravis-0.8.so.0")
    lib.arv_buffer_get_data.restype = ctypes.c_void_p
    lib.arv_buffer_get_data.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_size_t)]
    for name in ("arv_buffer_get_image_width", "arv_buffer_get_image_height"):
        getattr(lib, name).restype = ctypes.c_int
        getattr(lib, name).argtypes = [ctypes.c_void_p]
    lib.arv_fake_camera_set_fill_pattern.argtypes = [ctypes.c_void_p, _FILL, ctypes.c_void_p]
    lib.arv_fake_camera_set_fill_pattern.restype = None
    return Aravis, lib


def _gpointer(obj: Any) -> int:
    get = ctypes.pythonapi.PyCapsule_GetPointer
    get.restype, get.argtypes = ctypes.c_void_p, [ctypes.py_object, ctypes.c_char_p]
    return int(get(obj.__gpointer__, None))


class GvCamera:
    """A GigE Vision fake camera bound to ``address`` that renders ``world`` (or a test card)."""

    def __init__(
        self, world: World | None = None, *, address: str = "127.0.0.1", serial: str = "RVIS0001"
    ) -> None:
        self.world, self.address, self.serial = world, address, serial
        self.camera_id = address
        self.frames_filled = 0
        self.failed = False
        self._gv: Any = None
        self._fake: Any = None
        self._lib: ctypes.CDLL | None = None
        self._callback: Any = None

    def start(self) -> Self:
        aravis, self._lib = _aravis()
        self._gv = aravis.GvFakeCamera.new(self.address, self.serial)
        if not self._gv.is_running():
            raise RuntimeError(f"GvFakeCamera could not bind {self.address}")
        self._fake = self._gv.get_fake_camera()
        if self.world is not None:
            self._callback = _FILL(self._fill)
            self._lib.arv_fake_camera_set_fill_pattern(_gpointer(self._fake), self._callback, None)
        return self

    def close(self) -> None:
        if self._gv is None:
            return
        self._gv = None  # finalising the GvFakeCamera joins its thread
        self._fake = None
        import gc

        gc.collect()
        self._callback = None

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _fill(self, buffer: int, _: int, exposure_us: int, gain: int, pixel_format: int) -> None:
        # Runs on Aravis's camera thread: never let an exception cross into C.
        try:
            assert self._lib is not None and self.world is not None
            w = self._lib.arv_buffer_get_image_width(buffer)
            h = self._lib.arv_buffer_get_image_height(buffer)
            bits = (pixel_format >> 16) & 0xFF
            ptr = self._lib.arv_buffer_get_data(buffer, ctypes.byref(ctypes.c_size_t()))
            image = self.world.render_frame(w, h, float(exposure_us), float(gain), None)
            top, dtype = (255, np.uint8) if bits == 8 else (65535, np.dtype("<u2"))
            values = np.round(np.clip(image, 0.0, 1.0) * top).astype(dtype)
            raw = (ctypes.c_uint8 * (w * h * (bits // 8))).from_address(ptr)
            np.frombuffer(raw, dtype=dtype)[:] = values.ravel()
            self.frames_filled += 1
        except Exception:
            self.failed = True
