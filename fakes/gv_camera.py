"""Aravis's own GigE Vision fake camera on 127.0.0.1, serving frames rendered from a World.

``Aravis.GvFakeCamera`` runs in-process and answers a normal Aravis client over real UDP on
loopback (GVCP port 3956: one fake per address). Its image content comes from a fill callback
registered through ctypes (``arv_fake_camera_set_fill_pattern``): a PyGObject callback would be
freed too early and crash. The callback renders ``world.render_frame`` at the requested region
size (offsets are not passed to the callback) and quantises it to the pixel format. With
``sensor_wh=(w, h)`` the fake reports that sensor size (the rendered camera's, instead of
Aravis's 2048 x 2048) and the callback renders the full sensor and crops the region at the
offsets it reads from the fake's registers.

    with GvCamera(world) as gv:
        camera = AravisCamera(gv.camera_id)     # "127.0.0.1"

One fake per address in a network namespace: GVCP's port 3956 is bound once per address, and a
second fake (another test process, another worktree's suite) would take its packets. `start()`
therefore waits for a lock of the address in its network namespace (an flock in the temporary
folder, named by the namespace and the address, with the holder's pid in it) and `close()` gives
it back: processes take turns instead of stealing each other's frames. One that waits names the
holder with its command line (fakes/holders.py), and a bind that fails names the process that
holds the port, when /proc shows it. Processes in different
network namespaces (the test suite's workers, tests/netns.py) each have a loopback of their own
and do not wait for each other.

On the simulated line's VirtualClock (``clock=``) every frame lets its exposure and
``readout_s`` of sim time pass before it is rendered (the scene at the end of the exposure).

``stall()`` makes the camera stop sending frames while it still answers its control channel (a
camera that times out); ``resume()`` brings the frames back without a stale one for a trigger
that came in meanwhile. ``lose_next_frame()`` drops every packet of the next frame on the wire
(one frame lost; the camera goes on streaming).
"""

from __future__ import annotations

import contextlib
import ctypes
import fcntl
import os
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Self

import numpy as np

from fakes.clock import VirtualClock
from fakes.holders import flock_holder, process_text, udp_port_holder
from fakes.world import World, frame_in_format

_FILL = ctypes.CFUNCTYPE(
    None, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint32, ctypes.c_uint32, ctypes.c_uint32
)


#: Registers of Aravis's fake camera (its GenICam XML): acquisition (1 streaming, 0 stopped),
#: sensor and region size, region offsets.
_ACQUISITION_REGISTER = 0x124
_SENSOR_W, _SENSOR_H, _WIDTH, _HEIGHT, _OFFSET_X, _OFFSET_Y = (
    0x11C,
    0x118,
    0x100,
    0x104,
    0x130,
    0x134,
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


#: How long start() waits for another process's fake on the same address to close.
ADDRESS_WAIT_S = 600.0
#: GigE Vision's control port (GVCP), bound once per address
GVCP_PORT = 3956


def _network_namespace() -> str:
    """The calling thread's network namespace ("4026531840"; "" where /proc does not say)."""
    try:
        return str(os.stat("/proc/thread-self/ns/net").st_ino)
    except OSError:
        return ""


class _AddressLock:
    """An exclusive lock of one GVCP address in this network namespace (flock; the kernel drops
    it when the holder dies)."""

    def __init__(self, address: str) -> None:
        name = f"rvis-gv-fake-{_network_namespace()}-{address}.lock"
        self.address = address
        self.path = Path(tempfile.gettempdir()) / name
        self._fd: int | None = None

    def acquire(
        self, timeout_s: float | None, on_wait: Callable[[str], None] | None = None
    ) -> None:
        """Take the lock, waiting up to timeout_s (None: as long as it takes); when it must
        wait, `on_wait` gets one line naming the address and the holder, at once."""
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        said = False
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if deadline is not None and time.monotonic() > deadline:
                    holder = _holder(fd)
                    os.close(fd)
                    raise RuntimeError(
                        f"{self.path}: another fake GigE camera ({holder}) holds the address"
                    ) from None
                if not said and on_wait is not None:
                    said = True
                    on_wait(
                        f"waiting for the simulated GigE camera's address {self.address}"
                        f" (GVCP port {GVCP_PORT}, one camera per address), in use by another"
                        f" simulation, {_holder(fd)}: this one goes on when that one ends"
                    )
                time.sleep(0.05)  # another process's test is using the camera: wait its turn
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        self._fd = fd

    def release(self) -> None:
        if self._fd is not None:
            with contextlib.suppress(OSError):
                os.ftruncate(self._fd, 0)
            os.close(self._fd)
            self._fd = None


def _holder(fd: int) -> str:
    """The process holding the address lock open as `fd`, in words: the pid it wrote (or, not
    written yet, the flock's holder in /proc/locks) with its command line."""
    written = os.pread(fd, 16, 0).decode(errors="replace").strip()
    pid = int(written) if written.isdigit() else flock_holder(fd)
    return "pid unknown" if pid is None else process_text(pid)


def _gpointer(obj: Any) -> int:
    get = ctypes.pythonapi.PyCapsule_GetPointer
    get.restype, get.argtypes = ctypes.c_void_p, [ctypes.py_object, ctypes.c_char_p]
    return int(get(obj.__gpointer__, None))


class GvCamera:
    """A GigE Vision fake camera bound to ``address`` that renders ``world`` (or a test card)."""

    def __init__(
        self,
        world: World | None = None,
        *,
        address: str = "127.0.0.1",
        serial: str = "RVIS0001",
        sensor_wh: tuple[int, int] | None = None,
        clock: VirtualClock | None = None,
        readout_s: float = 0.0,
        wait_s: float | None = ADDRESS_WAIT_S,
        on_wait: Callable[[str], None] | None = None,
    ) -> None:
        """wait_s: how long `start` waits for the address when another fake holds it (None:
        as long as it takes); on_wait: told at once, in one line, when it must wait."""
        self.world, self.address, self.serial = world, address, serial
        self.wait_s, self.on_wait = wait_s, on_wait
        self.clock, self.readout_s = clock, float(readout_s)
        self.sensor_wh = sensor_wh
        self.camera_id = address
        self.frames_filled = 0
        self.frames_lost = 0
        self.failed = False
        self._lose = 0  # 1: drop the next frame's packets; 2: dropping the current one
        self._gv: Any = None
        self._fake: Any = None
        self._lib: ctypes.CDLL | None = None
        self._callback: Any = None
        self._lock = _AddressLock(address)

    def start(self) -> Self:
        aravis, self._lib = _aravis()
        self._lock.acquire(self.wait_s, self.on_wait)
        self._gv = aravis.GvFakeCamera.new(self.address, self.serial)
        if not self._gv.is_running():
            self._gv = None
            self._lock.release()
            pid = udp_port_holder(self.address, GVCP_PORT)
            held = "" if pid is None else f" (UDP port {GVCP_PORT} held by {process_text(pid)})"
            raise RuntimeError(f"GvFakeCamera could not bind {self.address}{held}")
        self._fake = self._gv.get_fake_camera()
        if self.sensor_wh is not None:
            w, h = self.sensor_wh
            for register, value in ((_SENSOR_W, w), (_SENSOR_H, h), (_WIDTH, w), (_HEIGHT, h)):
                self._fake.write_register(register, value)
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
        self._lock.release()

    def stall(self) -> None:
        """Stop streaming (the fake's acquisition register off): grabs time out."""
        if self._fake is not None:
            self._fake.write_register(_ACQUISITION_REGISTER, 0)

    def resume(self) -> None:
        """Stream again; a software trigger received while stalled is dropped, not answered."""
        if self._fake is not None:
            self._fake.check_and_acknowledge_software_trigger()
            self._fake.write_register(_ACQUISITION_REGISTER, 1)

    def lose_next_frame(self) -> None:
        """The next frame sent is lost on the wire (all its GVSP packets dropped): the client's
        grab times out; the frame after it arrives again."""
        self._lose = 1

    def _drop_packets(self) -> None:
        """Called from the fill callback, before the frame's packets are sent: the fake's
        lost-packet ratio is 1 for the frame to lose and back to 0 for the next one."""
        if self._lose == 1:
            self._gv.set_property("gvsp-lost-ratio", 1.0)
            self._lose, self.frames_lost = 2, self.frames_lost + 1
        elif self._lose == 2:
            self._gv.set_property("gvsp-lost-ratio", 0.0)
            self._lose = 0

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
            if self.clock is not None:
                self.clock.elapse(exposure_us * 1e-6 + self.readout_s)
            top = 255 if bits == 8 else 65535
            values = self._render(w, h, float(exposure_us), float(gain), top)
            raw = (ctypes.c_uint8 * (w * h * (bits // 8))).from_address(ptr)
            np.frombuffer(raw, dtype=values.dtype)[:] = values.ravel()
            self.frames_filled += 1
            if self._lose:
                self._drop_packets()
        except Exception:
            self.failed = True

    def _render(self, w: int, h: int, exposure_us: float, gain: float, top: int) -> Any:
        """The world's frame in the pixel format of maximum value `top`, w x h from the
        region's offset."""
        assert self.world is not None and self._fake is not None
        if self.sensor_wh is None:
            return frame_in_format(self.world, (w, h), exposure_us, gain, None, top)
        full = frame_in_format(self.world, self.sensor_wh, exposure_us, gain, None, top)
        x = int(self._fake.read_register(_OFFSET_X)[1])
        y = int(self._fake.read_register(_OFFSET_Y)[1])
        return full[y : y + h, x : x + w]
