"""Camera contract: one test body per behaviour, run on fake://, Aravis against its GigE Vision
fake camera on 127.0.0.1 over real UDP (skipped where Aravis/PyGObject are not installed) and a
real camera (``RVIS_CAMERA_URL``, e.g. ``aravis://Basler-21234567``; its hardware trigger line
must be idle). The image content is checked against the world where a fake renders it."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import ExitStack
from dataclasses import dataclass, replace

import numpy as np
import pytest

from drivers import DeviceConfigError, DeviceConnectionError, DeviceTimeout, open_camera
from drivers.camera import Camera, CameraSettings
from fakes.devices import FakeCamera, FakeGalvo
from fakes.world import StaticWorld
from tests.drivers.backends import HARDWARE, backends, real_url
from tests.groups import GIGE_CAMERA


def _aravis_available() -> bool:
    try:
        import drivers.aravis_camera  # noqa: F401
    except ImportError:
        return False
    return True


ARAVIS = pytest.mark.skipif(not _aravis_available(), reason="Aravis 0.8 / PyGObject missing")
SETTINGS = CameraSettings(region=(0, 0, 320, 240), exposure_us=10_000.0, gain_db=0.0)


@dataclass
class CameraRig:
    camera: Camera
    world: StaticWorld | None  # what the fake renders; None on a real camera
    streams_world: bool = False  # the frames are the world's render, pixel for pixel


@pytest.fixture(
    params=backends("camera", ["fake", pytest.param("aravis", marks=[ARAVIS, GIGE_CAMERA])])
)
def rig(request: pytest.FixtureRequest, world: StaticWorld) -> Iterator[CameraRig]:
    with ExitStack() as stack:
        if request.param == HARDWARE:
            cam = stack.enter_context(open_camera(real_url("camera"), settings=SETTINGS))
            yield CameraRig(cam, None)
        elif request.param == "fake":
            cam = stack.enter_context(open_camera("fake://", settings=SETTINGS, world=world))
            yield CameraRig(cam, world)  # renders the full sensor and crops the region
        else:
            from fakes.gv_camera import GvCamera

            gv = stack.enter_context(GvCamera(world))
            url = f"aravis://{gv.camera_id}"
            cam = stack.enter_context(open_camera(url, settings=SETTINGS, timeout_s=2.0))
            yield CameraRig(cam, world, streams_world=True)


def expected(world: StaticWorld, w: int, h: int, top: int) -> np.ndarray:
    return np.round(np.clip(world.render_frame(w, h, 10_000.0, 0.0, None), 0, 1) * top)


def test_software_triggered_frames_carry_the_image(rig: CameraRig) -> None:
    first, second = rig.camera.grab(), rig.camera.grab()
    assert first.image.shape == (240, 320) and first.image.dtype == np.uint8
    assert second.frame_id != first.frame_id and second.timestamp_ns >= first.timestamp_ns
    assert second.exposure_us == pytest.approx(rig.camera.settings.exposure_us)
    if rig.streams_world:
        assert rig.world is not None
        np.testing.assert_array_equal(second.image, expected(rig.world, 320, 240, 255))


def test_region_exposure_and_16_bit(rig: CameraRig) -> None:
    wanted = CameraSettings(region=(0, 0, 160, 120), exposure_us=5000.0, pixel_format="Mono16")
    try:
        applied = rig.camera.configure(wanted)
    except DeviceConfigError as exc:  # a real camera offering Mono12 but not Mono16
        assert rig.world is None and "not offered" in str(exc)
        applied = rig.camera.configure(replace(wanted, pixel_format="Mono12"))
    assert applied.region == (0, 0, 160, 120)
    assert applied.exposure_us == pytest.approx(5000.0, rel=0.02)  # cameras round to their step
    frame = rig.camera.grab()
    assert frame.image.shape == (120, 160) and frame.image.dtype == np.uint16
    top = 65535 if applied.pixel_format == "Mono16" else 4095
    assert frame.image.max() <= top
    if rig.world is not None:  # the world's ramp is brighter than any 8-bit code
        assert frame.image.max() > 255


def test_bad_settings_are_configuration_errors(rig: CameraRig) -> None:
    camera = rig.camera
    w, h = camera.sensor_size()
    with pytest.raises(DeviceConfigError):
        camera.configure(CameraSettings(region=(0, 0, w + 1, h)))
    with pytest.raises(DeviceConfigError):
        camera.configure(CameraSettings(exposure_us=-1))
    assert camera.settings.region == (0, 0, 320, 240)  # unchanged


def test_hardware_trigger_without_an_edge_times_out(rig: CameraRig) -> None:
    rig.camera.configure(CameraSettings(region=(0, 0, 64, 48), trigger="hardware"))
    with pytest.raises(DeviceTimeout):
        rig.camera.grab(timeout_s=0.2)


def test_fake_hardware_trigger_and_galvo_line(world: StaticWorld) -> None:
    settings = CameraSettings(trigger="hardware")
    with FakeGalvo() as galvo, FakeCamera(world, galvo=galvo, settings=settings) as cam:
        galvo.set_volts(5.0)
        cam.fire_line_trigger()
        frame = cam.grab(timeout_s=0.5)
        column = int(np.argmax(frame.image.mean(axis=0)))
        assert abs(column - 0.75 * (frame.image.shape[1] - 1)) <= 2  # +5 V: 3/4 across


@ARAVIS
def test_aravis_unknown_camera_is_a_connection_error() -> None:
    with pytest.raises(DeviceConnectionError, match="not found"):
        open_camera("aravis://no-such-camera-0000", timeout_s=0.5)


@ARAVIS
@GIGE_CAMERA
def test_aravis_mono12_refused_when_not_offered(world: StaticWorld) -> None:
    from fakes.gv_camera import GvCamera

    with ExitStack() as stack:
        gv = stack.enter_context(GvCamera(world))
        cam = stack.enter_context(open_camera(f"aravis://{gv.camera_id}", settings=SETTINGS))
        with pytest.raises(DeviceConfigError, match="Mono12"):
            cam.configure(CameraSettings(pixel_format="Mono12"))


@ARAVIS
@GIGE_CAMERA
def test_aravis_stream_stops_when_the_camera_vanishes(world: StaticWorld) -> None:
    from fakes.gv_camera import GvCamera

    settings = CameraSettings(region=(0, 0, 64, 48), trigger="free", buffers=2)
    url = "aravis://127.0.0.1"
    gv = GvCamera(world).start()
    try:
        with open_camera(url, settings=settings, timeout_s=0.3) as cam:
            try:
                cam.grab()
            except DeviceTimeout:  # a first buffer left unfilled on a loaded machine (the
                cam.grab()  # driver made a new stream): streaming, the next one comes
            gv.close()  # gone mid-acquisition: what is queued drains, then nothing comes
            with pytest.raises(DeviceTimeout):
                for _ in range(settings.buffers + 2):
                    cam.grab()
            gv = GvCamera(world).start()  # back (power-cycled): the old stream stays silent
        with open_camera(url, settings=settings, timeout_s=1.0) as cam:
            np.testing.assert_array_equal(cam.grab().image, expected(world, 64, 48, 255))
    finally:
        gv.close()


@ARAVIS
@GIGE_CAMERA
def test_aravis_lost_control_channel_fails_fast_until_reopened(world: StaticWorld) -> None:
    """A software trigger to a vanished camera times out once (Aravis's own GVCP retries,
    about 2.5 s); after that the camera is lost and calls fail at once, with no stop request."""
    from fakes.gv_camera import GvCamera

    settings = CameraSettings(region=(0, 0, 64, 48), trigger="software")
    url = "aravis://127.0.0.1"
    gv = GvCamera(world).start()
    try:
        with open_camera(url, settings=settings, timeout_s=0.3) as cam:
            try:
                cam.grab()
            except DeviceTimeout:  # a first buffer left unfilled on a loaded machine (the
                cam.grab()  # driver made a new stream): streaming, the next one comes
            gv.close()
            with pytest.raises(DeviceTimeout, match="software trigger"):
                cam.grab()
            with pytest.raises(DeviceConnectionError, match="lost"):
                cam.grab()
            with pytest.raises(DeviceConnectionError, match="lost"):
                cam.configure(settings)
            gv = GvCamera(world).start()
        with open_camera(url, settings=settings, timeout_s=1.0) as cam:
            np.testing.assert_array_equal(cam.grab().image, expected(world, 64, 48, 255))
    finally:
        gv.close()
