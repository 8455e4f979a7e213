"""The camera backends through the real SDKs: pypylon's emulated cameras serve the rendered
scene bit for bit at 8 and 12 bits, a missing trigger edge times out in one line, a pair out
of step or a dropped frame is captured again and never measured; the one ``--cameras``
parser and the cell's ``[cameras]`` section; the recorded-folder backend."""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("PYLON_CAMEMU", "2")  # before pypylon lists its cameras

import cv2
import numpy as np
import pytest

from quickhealth.identify.errors import HardwareError, InputError
from quickhealth.station.hardware.cameras.config import (
    CameraConfig,
    Trigger,
    choose,
    parse_cameras_option,
)
from quickhealth.station.hardware.cameras.files import FilesStereoCamera
from quickhealth.station.hardware.cameras.genicam import TriggeredStereoCamera
from quickhealth.station.hardware.line_trigger import Pulse, line_trigger
from quickhealth.station.planning.cell import parse_cell
from quickhealth.station.sim.cameras import EmulatorFeed, SimStereoCamera, scaled_rig
from quickhealth.station.sim.cell import emulated_cameras
from quickhealth.station.sim.world import build_world
from quickhealth.vision.pose7d import PoseMeasurement, measure_stereo
from quickhealth.vision.render import Imaging

Q = np.radians([-66.67, -79.81, 68.28, -61.82, -156.02, -110.86])  # a pose of a reference plan
PAN = np.radians(-35.83)


@pytest.fixture(scope="module")
def world():  # type: ignore[no-untyped-def]
    return build_world("reference", twin_seed=1)


def renderer(world, bits: int, seed: int = 0) -> SimStereoCamera:  # type: ignore[no-untyped-def]
    T = world.T_instr_plate(Q, PAN)
    return SimStereoCamera(
        scaled_rig(world.rig, 0.25),
        lambda: [(T, world.target)],
        static=[(world.T_instr_board, world.board)],
        seed=seed,
        imaging=Imaging(bits=bits),
    )


def pylon(bits: int, **changes: object) -> CameraConfig:
    fmt = {8: "Mono8", 12: "Mono12"}[bits]
    return replace(choose(None, "pylon"), **{"pixel_format": fmt, "timeout_s": 0.3, **changes})


@pytest.mark.parametrize("bits", [8, 12])
def test_emulated_pylon_cameras_serve_the_rendered_pair_bit_for_bit(world, bits: int) -> None:  # type: ignore[no-untyped-def]
    r = renderer(world, bits)
    cam = emulated_cameras(pylon(bits), r)
    try:
        assert isinstance(cam, TriggeredStereoCamera)
        feed = cam._prepare
        assert isinstance(feed, EmulatorFeed)
        ids = [c.serial for c in cam.identities]
        assert ids == ["0815-0000", "0815-0001"] and all(c.firmware for c in cam.identities)
        for k in range(2):
            frame = cam.capture()
            assert frame.bits == bits and frame.trigger == "software"
            assert frame.left.dtype == (np.uint8 if bits == 8 else np.uint16)
            assert feed.shown is not None
            assert np.array_equal(frame.left, feed.shown[0])
            assert np.array_equal(frame.right, feed.shown[1])
            assert frame.left.max() > (200 if bits == 8 else 3200)  # 12 bits used, not 8
            assert [i.frame_id for i in frame.info] == [k + 1, k + 1]
        # the same images measure the same: the emulator changes nothing
        m_cam = measure_stereo(r.rig, world.target, frame.left, frame.right, bits=bits)
        m_ren = measure_stereo(r.rig, world.target, *feed.shown, bits=bits)
        assert isinstance(m_cam, PoseMeasurement) and isinstance(m_ren, PoseMeasurement)
        assert np.max(np.abs(m_cam.position - m_ren.position)) <= 1e-9  # 1 nm
    finally:
        cam.close()


def test_a_missing_trigger_edge_times_out_in_one_line(world) -> None:  # type: ignore[no-untyped-def]
    """Hardware trigger (Line1) with no edge: the emulator delivers nothing, as a camera
    whose trigger cable is off; the capture fails in one line and gives no frame."""
    cfg = pylon(8, trigger=Trigger.EXTERNAL, attempts=2, timeout_s=0.2)
    cam = emulated_cameras(cfg, renderer(world, 8))
    try:
        with pytest.raises(HardwareError) as err:
            cam.capture()
        msg = str(err.value)
        assert "\n" not in msg and "no good stereo pair in 2 attempts" in msg
        assert "missing trigger edge" in msg and "--resume" in msg
        assert cam.stats["timeouts"] >= 2 and cam.stats["pairs"] == 0
    finally:
        cam.close()


def test_a_pair_out_of_step_is_captured_again(world) -> None:  # type: ignore[no-untyped-def]
    """A stray edge on one camera's line (here: one software trigger to the left camera
    alone) puts a frame nobody asked for in its queue: the pair is out of step, discarded,
    and the pair delivered is the scene in front of the cameras at the trigger."""
    cam = emulated_cameras(pylon(8), renderer(world, 8))
    try:
        cam.capture()
        feed = cam._prepare

        def stray(devs):  # type: ignore[no-untyped-def]
            feed(devs)
            left = devs[0]
            left.trigger()  # an edge only the left camera saw
            import time

            t0 = time.monotonic()
            while not left.pending() and time.monotonic() - t0 < 2.0:
                time.sleep(0.005)

        cam._prepare = stray
        frame = cam.capture()
        assert cam.stats["out_of_step"] == 1
        assert "out of step" in " ".join(frame.meta["attempt_problems"])
        assert np.array_equal(frame.left, feed.shown[0])
        assert np.array_equal(frame.right, feed.shown[1])
    finally:
        cam.close()


def test_a_dropped_frame_is_captured_again(world) -> None:  # type: ignore[no-untyped-def]
    """The emulator fails the next buffer (lost packets): that pair is never measured."""
    cam = emulated_cameras(pylon(8), renderer(world, 8))
    try:
        cam.capture()
        feed = cam._prepare

        def drop(devs):  # type: ignore[no-untyped-def]
            feed(devs)
            if cam.stats["dropped"] == 0:
                devs[1].cam.ForceFailedBufferCount.Value = 1
                devs[1].cam.ForceFailedBuffer.Execute()

        cam._prepare = drop
        frame = cam.capture()
        assert cam.stats["dropped"] == 1
        assert np.array_equal(frame.right, feed.shown[1])
    finally:
        cam.close()


def test_one_parser_for_cameras() -> None:
    assert parse_cameras_option("pylon") == ("pylon", None)
    assert parse_cameras_option("pylon:40012345,40012346") == ("pylon", ("40012345", "40012346"))
    assert parse_cameras_option("0,1") == ("opencv", ("0", "1"))
    assert parse_cameras_option("files:runs/n1/images") == ("files", ("runs/n1/images",) * 2)
    for bad in ("gopro", "pylon:1", "pylon:a,b,c", "files:", "pylon:a;rm,b"):
        with pytest.raises(InputError) as err:
            parse_cameras_option(bad)
        assert "\n" not in str(err.value)


CELL = (Path(__file__).resolve().parents[2] / "station/data/reference_cell.toml").read_text()


def test_the_cells_cameras_section() -> None:
    text = CELL + (
        '\n[cameras]\nbackend = "pylon"\npixel_format = "Mono12"\ntrigger = "line"\n'
        "robot_output = 2\npulse_ms = 16\nexposure_us = 8000\ntimeout_ms = 500\n"
        '[cameras.left]\nid = "40012345"\n[cameras.right]\nid = "cam-right"\ngain_db = 3\n'
    )
    cell = parse_cell(text.encode(), "cell.toml")
    c = cell.cameras
    assert c is not None and c.backend == "pylon" and c.bits == 12
    assert c.trigger is Trigger.LINE and c.robot_output == 2 and c.timeout_s == 0.5
    assert c.pulse_s == 0.016 and "robot output 2, 16 ms pulse" in c.describe()
    assert c.ids == ("40012345", "cam-right") and c.right.gain_db == 3.0
    assert c.left.exposure_us == 8000.0
    # --cameras names other cameras of the same backend: the cell's settings stay
    c2 = choose(c, "pylon:A,B")
    assert c2.ids == ("A", "B") and c2.bits == 12 and c2.trigger is Trigger.LINE
    # another backend starts from the defaults
    assert choose(c, "opencv:0,1").bits == 8
    with pytest.raises(InputError, match=r"cell.toml: cameras.pixel_format: 'Mono11'"):
        parse_cell(text.replace("Mono12", "Mono11").encode(), "cell.toml")
    with pytest.raises(InputError, match=r"cameras.trigger: 'line' needs cameras with a trigger"):
        parse_cell(text.replace('"pylon"', '"opencv"').encode(), "cell.toml")  # webcams
    with pytest.raises(InputError, match=r"cameras.pulse_ms"):  # shorter than any cycle pair
        parse_cell(text.replace("pulse_ms = 16", "pulse_ms = 1").encode(), "cell.toml")
    with pytest.raises(InputError, match="cameras.left.serial: unknown key"):
        parse_cell(text.replace('id = "40012345"', 'serial = "1"').encode(), "cell.toml")


class _Controller:
    """A robot controller's digital output at the hardware boundary (125 Hz, a CB3)."""

    sample_period = 0.008

    def __init__(self) -> None:
        self.pulses: list[tuple[int, float]] = []

    def pulse_digital_out(self, output: int, width_s: float) -> Pulse:
        self.pulses.append((output, width_s))
        return Pulse(output, 12.0, 12.0 + width_s, 0.004, 3e-6, 11.992, 12.0 + width_s - 0.008)


def test_the_line_trigger_is_the_robots_output_or_refused_in_one_line(world) -> None:  # type: ignore[no-untyped-def]
    cfg = replace(choose(None, "pylon"), trigger=Trigger.LINE, robot_output=2, pulse_s=0.02)
    assert line_trigger(object(), replace(cfg, trigger=Trigger.SOFTWARE)) is None
    with pytest.raises(InputError, match="needs a robot whose controller drives") as err:
        line_trigger(object(), cfg)  # e.g. the in-process fake robot: no digital output
    assert "\n" not in str(err.value)
    ur = _Controller()
    with pytest.raises(InputError, match=r"pulse_ms = 10 is shorter than two controller cycles"):
        line_trigger(ur, replace(cfg, pulse_s=0.01))  # could begin and end inside one cycle
    fire = line_trigger(ur, cfg)
    assert fire is not None and fire()["output"] == 2 and ur.pulses == [(2, 0.02)]
    assert fire() == {
        "output": 2,
        "rise_t": 12.0,
        "rise_window_ms": 8.0,
        "width_ms": 20.0,
        "latency_ms": 4.0,
        "rest_urad": 3.0,
    }
    for backend, words in (("aravis", "pylon's emulated cameras only"), ("pylon", "trigger cable")):
        with pytest.raises(InputError, match=words):  # --sim: no cable, or free-running fakes
            emulated_cameras(replace(cfg, backend=backend), renderer(world, 8))
    with pytest.raises(HardwareError, match="needs the robot's digital output"):
        TriggeredStereoCamera(object, scaled_rig(world.rig, 0.25), cfg)


def test_a_recorded_folder_plays_its_pairs_in_order(tmp_path: Path, world) -> None:  # type: ignore[no-untyped-def]
    r = renderer(world, 12)
    shots = [r.capture() for _ in range(2)]
    for k, f in enumerate(shots):
        for side, img in (("L", f.left), ("R", f.right)):
            assert cv2.imwrite(str(tmp_path / f"{k:04d}_P{k}_{side}.png"), img)
    cam = FilesStereoCamera(tmp_path, r.rig, bits=12)
    for f in shots:
        got = cam.capture()
        assert (
            got.bits == 12
            and np.array_equal(got.left, f.left)
            and np.array_equal(got.right, f.right)
        )
    with pytest.raises(HardwareError, match="no more image pairs"):
        cam.capture()


@pytest.fixture
def aravis() -> None:
    """Aravis 0.8 and PyGObject (``make aravis``): required under make test, CI or root."""
    try:
        import gi

        gi.require_version("Aravis", "0.8")
        from gi.repository import Aravis  # noqa: F401
    except (ImportError, ValueError) as exc:
        from qh_required import unavailable

        unavailable(f"Aravis 0.8 with PyGObject is not installed ({exc}): make aravis")


def test_aravis_fake_cameras_serve_the_rendered_pair_bit_for_bit(world, aravis) -> None:  # type: ignore[no-untyped-def]
    """Through Aravis' GenICam stack (its in-process fake cameras: no network needed)."""
    r = renderer(world, 8)
    cam = emulated_cameras(choose(None, "aravis"), r)
    try:
        assert [(c.vendor, c.model) for c in cam.identities] == [("Aravis", "Fake")] * 2
        assert [c.serial for c in cam.identities] == ["QH-SIM-L", "QH-SIM-R"]
        for _ in range(2):
            frame = cam.capture()
            assert np.array_equal(frame.left, cam._prepare.shown[0])
            assert np.array_equal(frame.right, cam._prepare.shown[1])
        m = measure_stereo(r.rig, world.target, frame.left, frame.right)
        m_ren = measure_stereo(r.rig, world.target, *cam._prepare.shown)
        assert isinstance(m, PoseMeasurement) and isinstance(m_ren, PoseMeasurement)
        assert np.max(np.abs(m.position - m_ren.position)) <= 1e-9
        with pytest.raises(HardwareError, match="has no Mono12"):
            emulated_cameras(replace(choose(None, "aravis"), pixel_format="Mono12"), r)
    finally:
        cam.close()
