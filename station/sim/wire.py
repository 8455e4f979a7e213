"""RTDE wire format of a UR controller: ports, packets, field types, recipes, versions.

Everything the simulator must pack exactly as the ur-rtde client unpacks it
(``notes/ur-rtde.md``).  The client ignores the type string of a setup reply and unpacks
with its own table (``robot_state.cpp``), so one wrongly sized field silently shifts every
later one: :data:`FIXED_TYPES` and :func:`rtde_type` follow that table.
"""

from __future__ import annotations

import ipaddress
import socket
import struct
from typing import Any

HOST = "127.0.0.1"


def check_loopback(host: str) -> str:
    """``host`` when it is an IPv4 loopback address (127.0.0.0/8); the simulator serves
    nowhere else.  Raises ValueError otherwise."""

    try:
        ok = ipaddress.IPv4Address(host).is_loopback
    except ValueError:
        ok = False
    if not ok:
        raise ValueError(
            f"the simulator serves on loopback addresses only (127.x.y.z), not {host!r}"
        )
    return host


RTDE_PORT = 30004
DASHBOARD_PORT = 29999
SCRIPT_PORT = 30003
CONTROL_PORT = 30090

CB3_VERSION = (3, 15, 7, 106331)  # the default: the client streams at 125 Hz
CONTROLLER_VERSION = CB3_VERSION
E_SERIES_VERSION = (5, 11, 1, 0)  # what an e-Series arm's simulator reports: 500 Hz


def version_for(controller: str) -> tuple[int, int, int, int]:
    """The software version the simulator of an arm of this controller generation reports
    (``RobotModel.controller``: ``"e-Series"`` → 5.11.1, anything else → CB3 3.15.7)."""
    return E_SERIES_VERSION if controller == "e-Series" else CB3_VERSION


def dashboard_model(robot_name: str) -> str:
    """The dashboard server's answer to ``get robot model`` for a built-in arm.

    UR's dashboard names the arm without its series (``UR10`` on a UR10 and on a UR10e,
    ``UR16`` on a UR16e, ``UR20``, ``UR30``); the software version (``PolyscopeVersion``, 3.x
    against 5.x) tells a CB3 from an e-Series.
    """
    name = robot_name.strip().upper()
    return name[:-1] if name.endswith("E") else name


# RTDE packet types.
P_REQUEST_PROTOCOL_VERSION = ord("V")
P_GET_URCONTROL_VERSION = ord("v")
P_TEXT_MESSAGE = ord("M")
P_DATA = ord("U")
P_SETUP_OUTPUTS = ord("O")
P_SETUP_INPUTS = ord("I")
P_START = ord("S")
P_PAUSE = ord("P")

# RTDE field types as the client packs them (its own table, robot_state.cpp).
TYPE_FMT = {
    "DOUBLE": "d",
    "VECTOR6D": "6d",
    "VECTOR3D": "3d",
    "UINT64": "Q",
    "UINT32": "I",
    "INT32": "i",
    "VECTOR6INT32": "6i",
    "VECTOR6UINT32": "6I",
    "UINT8": "B",
    "BOOL": "?",
}
# Input-only names (the client writes them; an output recipe may read them back).
INPUT_FIELDS = {
    "speed_slider_mask": "UINT32",
    "speed_slider_fraction": "DOUBLE",
    "standard_digital_output_mask": "UINT8",
    "standard_digital_output": "UINT8",
    "configurable_digital_output_mask": "UINT8",
    "configurable_digital_output": "UINT8",
    "tool_digital_output_mask": "UINT8",
    "tool_digital_output": "UINT8",
    "standard_analog_output_mask": "UINT8",
    "standard_analog_output_type": "UINT8",
    "standard_analog_output_0": "DOUBLE",
    "standard_analog_output_1": "DOUBLE",
    "input_bit_registers0_to_31": "UINT32",
    "input_bit_registers32_to_63": "UINT32",
    "external_force_torque": "VECTOR6D",
}
FIXED_TYPES = {
    "timestamp": "DOUBLE",
    "actual_digital_input_bits": "UINT64",
    "actual_digital_output_bits": "UINT64",
    "actual_execution_time": "DOUBLE",
    "robot_mode": "INT32",
    "joint_mode": "VECTOR6INT32",
    "safety_mode": "INT32",
    "safety_status": "INT32",
    "actual_tool_accelerometer": "VECTOR3D",
    "speed_scaling": "DOUBLE",
    "target_speed_fraction": "DOUBLE",
    "actual_momentum": "DOUBLE",
    "actual_main_voltage": "DOUBLE",
    "actual_robot_voltage": "DOUBLE",
    "actual_robot_current": "DOUBLE",
    "runtime_state": "UINT32",
    "elbow_position": "VECTOR3D",
    "elbow_velocity": "VECTOR3D",
    "robot_status_bits": "UINT32",
    "safety_status_bits": "UINT32",
    "analog_io_types": "UINT32",
    "io_current": "DOUBLE",
    "euromap67_input_bits": "UINT32",
    "euromap67_output_bits": "UINT32",
    "euromap67_24V_voltage": "DOUBLE",
    "euromap67_24V_current": "DOUBLE",
    "tool_mode": "UINT32",
    "tool_analog_input_types": "UINT32",
    "tool_output_voltage": "INT32",
    "tool_output_current": "DOUBLE",
    "tool_temperature": "DOUBLE",
    "tool_force_scalar": "DOUBLE",
    "output_bit_registers0_to_31": "UINT32",
    "output_bit_registers32_to_63": "UINT32",
    "payload": "DOUBLE",
    "payload_cog": "VECTOR3D",
    "payload_inertia": "VECTOR6D",
    "script_control_line": "UINT32",
    "ft_raw_wrench": "VECTOR6D",
    # the inputs (an output recipe may read them back); external_force_torque is a VECTOR6D
    **{n: t for n, t in INPUT_FIELDS.items() if n != "external_force_torque"},
}
VECTOR6D_FIELDS = (
    "target_q",
    "target_qd",
    "target_qdd",
    "target_current",
    "target_moment",
    "actual_q",
    "actual_qd",
    "actual_qdd",
    "actual_current",
    "actual_moment",
    "joint_control_output",
    "actual_TCP_pose",
    "actual_TCP_speed",
    "actual_TCP_force",
    "target_TCP_pose",
    "target_TCP_speed",
    "joint_temperatures",
    "actual_joint_voltage",
    "actual_current_as_torque",
    "external_force_torque",
)


# The field names of UR's RTDE guide ("Field names and associated types"), with the type
# the ur-rtde client unpacks each as.  Outputs (controller → client) and inputs (client →
# controller) are separate lists; every input register and input field can also be read
# back in an output recipe (the guide lists them among the outputs).  A name in neither
# list is ``NOT_FOUND``, whatever it starts with.
_GUIDE_OUTPUTS_EXTRA = {
    "standard_analog_input0": "DOUBLE",
    "standard_analog_input1": "DOUBLE",
    "standard_analog_output0": "DOUBLE",
    "standard_analog_output1": "DOUBLE",
    "tool_analog_input0": "DOUBLE",
    "tool_analog_input1": "DOUBLE",
    "tcp_force_scalar": "DOUBLE",
    "tcp_offset": "VECTOR6D",
    "actual_current_window": "VECTOR6D",
    "tool_output_mode": "UINT8",
    "tool_digital_output0_mode": "UINT8",
    "tool_digital_output1_mode": "UINT8",
    "joint_position_deviation_ratio": "DOUBLE",
    "collision_detection_ratio": "DOUBLE",
    "time_scale_source": "INT32",
}
_OUTPUT_ONLY_FIXED = {
    n: t for n, t in FIXED_TYPES.items() if n not in INPUT_FIELDS and n != "tool_force_scalar"
}
OUTPUT_FIELDS = {
    **_OUTPUT_ONLY_FIXED,
    # actual_qdd and actual_moment are not in the guide; external_force_torque is an input
    **{
        n: "VECTOR6D"
        for n in VECTOR6D_FIELDS
        if n not in ("external_force_torque", "actual_qdd", "actual_moment")
    },
    **_GUIDE_OUTPUTS_EXTRA,
}
# Register ranges of the guide: int and double registers 0..47 (0-23 for fieldbuses, 24-47
# for RTDE clients), single bit registers 64..127 (0-63 go by the 32-bit words above).
REGISTER_RANGES = {
    "output_int_register_": ("INT32", range(48)),
    "output_double_register_": ("DOUBLE", range(48)),
    "output_bit_register_": ("BOOL", range(64, 128)),
    "input_int_register_": ("INT32", range(48)),
    "input_double_register_": ("DOUBLE", range(48)),
    "input_bit_register_": ("BOOL", range(64, 128)),
}


def _register_type(name: str) -> str | None:
    for prefix, (typ, rng) in REGISTER_RANGES.items():
        if name.startswith(prefix):
            idx = name[len(prefix) :]
            if idx.isdigit() and str(int(idx)) == idx and int(idx) in rng:
                return typ
            return None
    return None


def rtde_type(name: str, direction: str = "output") -> str | None:
    """RTDE type of field ``name`` in an ``"output"`` or ``"input"`` recipe, None when UR's
    guide does not list it (the controller answers ``NOT_FOUND``)."""
    reg = _register_type(name)
    if direction == "input":
        if reg is not None:
            return reg if name.startswith("input_") else None
        return INPUT_FIELDS.get(name)
    if reg is not None:
        return reg
    return OUTPUT_FIELDS.get(name) or INPUT_FIELDS.get(name)


def parse_version(text: str) -> tuple[int, int, int, int]:
    """``"5.11.1"`` or ``"5.11.1.108318"`` → ``(major, minor, bugfix, build)``.

    Raises
    ------
    ValueError
        Not three or four non-negative integers, or a major version below 3.
    """
    parts = text.strip().split(".")
    try:
        nums = [int(p) for p in parts]
    except ValueError:
        nums = []
    if len(nums) not in (3, 4) or any(n < 0 or n > 1_000_000 for n in nums) or nums[0] < 3:
        raise ValueError(
            f"controller version {text[:40]!r}: expected MAJOR.MINOR.BUGFIX[.BUILD], e.g. 5.11.1 "
            "(major 3 = CB3, 5 = e-Series)"
        )
    if len(nums) == 3:
        nums.append(CB3_VERSION[3] if tuple(nums) == CB3_VERSION[:3] else 0)
    return nums[0], nums[1], nums[2], nums[3]


def max_stream_hz(version: tuple[int, ...]) -> float:
    """Highest RTDE output rate of a controller: 125 Hz on CB3, 500 Hz on e-Series (major > 3)."""
    return 500.0 if version[0] > 3 else 125.0


PROTOCOL_VERSIONS = (1, 2)  # the RTDE protocol versions a controller accepts (guide §2)


def packet(ptype: int, payload: bytes) -> bytes:
    """One RTDE packet: ``>HB`` header (size including the header, type) and the payload."""
    return struct.pack(">HB", len(payload) + 3, ptype) + payload


def recv_exact(conn: socket.socket, n: int) -> bytes:
    """Exactly ``n`` bytes from ``conn``; raises ConnectionError when the peer closes first."""
    buf = b""
    while len(buf) < n:
        chunk = conn.recv(n - len(buf))
        if not chunk:
            raise ConnectionError("peer closed")
        buf += chunk
    return buf


class Recipe:
    """An output or input recipe: its id, field names and types, and the struct that packs them."""

    def __init__(self, rid: int, names: list[str], types: list[str]) -> None:
        self.id = rid
        self.names = names
        self.types = types
        self.struct = struct.Struct(">B" + "".join(TYPE_FMT[t] for t in types))

    def pack(self, state: dict[str, Any], protocol: int = 2) -> bytes:
        """The ``U`` payload of this recipe from a state dict (missing fields pack as zeros).

        Protocol 2 starts it with the recipe id; protocol 1 has none (one output recipe)."""
        vals: list[Any] = [self.id]
        for n, t in zip(self.names, self.types, strict=True):
            v = state.get(n)
            if t.startswith("VECTOR"):
                k = 3 if t == "VECTOR3D" else 6
                vals.extend(list(v) if v is not None else [0] * k)
            elif t == "DOUBLE":
                vals.append(float(v) if v is not None else 0.0)
            elif t == "BOOL":
                vals.append(bool(v))
            else:
                vals.append(int(v) if v is not None else 0)
        data = self.struct.pack(*vals)
        return data if protocol >= 2 else data[1:]

    def unpack(self, payload: bytes) -> dict[str, Any]:
        """Field values of a client's ``U`` payload of this recipe."""
        vals = list(self.struct.unpack(payload[: self.struct.size]))[1:]
        out: dict[str, Any] = {}
        for n, t in zip(self.names, self.types, strict=True):
            if t.startswith("VECTOR"):
                k = 3 if t == "VECTOR3D" else 6
                out[n], vals = vals[:k], vals[k:]
            else:
                out[n] = vals.pop(0)
        return out
