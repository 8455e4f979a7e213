"""Pan motor: the serial protocol, the pyserial driver and the pseudo-terminal emulator."""

from __future__ import annotations

import math
import struct

import pytest

from quickhealth.identify.errors import HardwareError
from quickhealth.station.hardware.motor import (
    CMD_READ,
    REPLY,
    FrameDecoder,
    SerialPanMotor,
    crc16,
    encode_frame,
)
from quickhealth.station.sim.motor_emulator import MotorEmulator


def test_crc16_is_ccitt_false():
    assert crc16(b"123456789") == 0x29B1  # the catalogue check value
    assert crc16(b"") == 0xFFFF


def test_decoder_resynchronises_after_noise_and_rejects_bad_checksums():
    good = encode_frame(1, CMD_READ | REPLY, bytes([0]) + struct.pack(">iB", 4500, 0))
    bad = bytearray(good)
    bad[-1] ^= 0xFF
    dec = FrameDecoder()
    stream = b"\x00\xaa\x13garbage\xaa" + bytes(bad) + b"\x55" + good
    frames = []
    for i in range(0, len(stream), 3):  # arrives in pieces
        frames += dec.feed(stream[i : i + 3])
    assert len(frames) == 1
    assert frames[0].cmd == CMD_READ | REPLY
    assert struct.unpack(">iB", frames[0].payload[1:]) == (4500, 0)
    assert dec.n_bad >= 1


@pytest.fixture
def motor():
    with MotorEmulator(speed_deg_s=720.0) as emu:
        # the driver's own reply timeout (0.2 s, a real motor's): a 30 ms one made the
        # emulator's reply race the test's load, and a retry test fail on a busy machine
        m = SerialPanMotor(emu.port, retries=2)
        yield m, emu
        m.close()


def test_move_reaches_target_within_resolution(motor):
    m, emu = motor
    m.ping()
    reached = m.move_to(math.radians(-37.25))
    assert math.degrees(reached) == pytest.approx(-37.25, abs=0.01)
    assert emu.position_deg() == pytest.approx(-37.25, abs=1e-9)
    assert math.degrees(m.position()) == pytest.approx(-37.25, abs=0.01)


@pytest.mark.parametrize("fault", ["garbage", "corrupt", "silent"])
def test_transient_line_faults_are_retried(motor, fault):
    m, emu = motor
    emu.inject(fault, count=2)  # the next two replies are damaged or missing
    assert math.degrees(m.move_to(math.radians(12.0))) == pytest.approx(12.0, abs=0.01)
    if fault != "garbage":
        assert m.stats.retries >= 2


def test_dead_line_times_out_with_one_clear_message(motor):
    m, emu = motor
    emu.inject("silent")
    with pytest.raises(HardwareError) as err:
        m.position()
    msg = str(err.value)
    assert "\n" not in msg
    assert "does not answer" in msg and "3 tries" in msg and "cable" in msg


def test_corrupted_replies_forever_is_a_clear_failure(motor):
    m, emu = motor
    emu.inject("corrupt")
    with pytest.raises(HardwareError, match="corrupted reply"):
        m.ping()


def test_out_of_range_and_stall_are_refused(motor):
    m, emu = motor
    with pytest.raises(HardwareError, match="outside"):
        m.move_to(math.radians(175.0))
    with pytest.raises(HardwareError, match="outside"):
        m.move_to(float("nan"))
    emu.inject("stall")
    with pytest.raises(HardwareError, match="fault"):
        m.move_to(math.radians(30.0))


def test_missing_port_is_a_hardware_error(tmp_path):
    with pytest.raises(HardwareError, match="cannot open"):
        SerialPanMotor(str(tmp_path / "ttyNOPE"))
