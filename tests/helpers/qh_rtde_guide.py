"""A protocol-level RTDE client written from UR's "Real-Time Data Exchange (RTDE) Guide".

Independent of the simulator's own wire module: it packs and unpacks with the guide's type
names from the controller's setup replies (section "Field names and associated types"), so
a reply whose type string does not match its data shows up as garbage here, whereas
ur-rtde ignores the type string.  Framing per protocol version as the guide's "Protocol"
section gives it:

- header ``uint16 size`` (header included), ``uint8 type`` for every package;
- ``RTDE_REQUEST_PROTOCOL_VERSION`` ('V'): ``uint16 version`` → ``uint8 accepted``;
- ``RTDE_GET_URCONTROL_VERSION`` ('v'): → ``uint32 major, minor, bugfix, build``;
- ``RTDE_CONTROL_PACKAGE_SETUP_OUTPUTS`` ('O'): version 2 ``double frequency`` + names →
  ``uint8 recipe id`` + types; version 1 names → types (no frequency, no id);
- ``RTDE_CONTROL_PACKAGE_SETUP_INPUTS`` ('I'): names → ``uint8 recipe id`` + types
  (``NOT_FOUND``, ``IN_USE``);
- ``RTDE_CONTROL_PACKAGE_START`` ('S') / ``PAUSE`` ('P'): → ``uint8 accepted``;
- ``RTDE_DATA_PACKAGE`` ('U'): version 2 ``uint8 recipe id`` + data; version 1 outputs have
  no recipe id.
"""

from __future__ import annotations

import socket
import struct
import time
from typing import Any

GUIDE_FORMATS = {
    "BOOL": "?",
    "UINT8": "B",
    "UINT32": "I",
    "UINT64": "Q",
    "INT32": "i",
    "DOUBLE": "d",
    "VECTOR3D": "3d",
    "VECTOR6D": "6d",
    "VECTOR6INT32": "6i",
    "VECTOR6UINT32": "6I",
}


class RtdeGuideClient:
    def __init__(self, host: str, port: int = 30004, timeout: float = 3.0) -> None:
        self.sock = socket.create_connection((host, port), timeout=timeout)
        self.protocol = 1
        self.outputs: dict[int, tuple[list[str], list[str]]] = {}
        self.inputs: dict[int, tuple[list[str], list[str]]] = {}

    def close(self) -> None:
        self.sock.close()

    def __enter__(self) -> RtdeGuideClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- framing ------------------------------------------------------------------------
    def send(self, ptype: str, payload: bytes = b"") -> None:
        self.sock.sendall(struct.pack(">HB", len(payload) + 3, ord(ptype)) + payload)

    def _exact(self, n: int) -> bytes:
        buf = b""
        while len(buf) < n:
            chunk = self.sock.recv(n - len(buf))
            if not chunk:
                raise ConnectionError("controller closed the connection")
            buf += chunk
        return buf

    def recv(self) -> tuple[str, bytes]:
        size, ptype = struct.unpack(">HB", self._exact(3))
        return chr(ptype), self._exact(size - 3)

    def reply(self, ptype: str) -> bytes:
        """The next package of ``ptype`` (data packages in between are skipped)."""
        while True:
            t, payload = self.recv()
            if t == ptype:
                return payload

    # -- setup ---------------------------------------------------------------------------
    def request_protocol_version(self, version: int) -> bool:
        self.send("V", struct.pack(">H", version))
        ok = self.reply("V")[0] == 1
        if ok:
            self.protocol = version
        return ok

    def controller_version(self) -> tuple[int, int, int, int]:
        self.send("v")
        return struct.unpack(">4I", self.reply("v")[:16])  # type: ignore[return-value]

    def setup_outputs(self, names: list[str], frequency: float = 125.0) -> tuple[int, list[str]]:
        body = ",".join(names).encode()
        if self.protocol >= 2:
            body = struct.pack(">d", frequency) + body
        self.send("O", body)
        rep = self.reply("O")
        if self.protocol >= 2:
            rid, types = rep[0], rep[1:].decode().split(",")
        else:
            rid, types = 1, rep.decode().split(",")
        if rid and not ({"NOT_FOUND", "IN_USE"} & set(types)):
            self.outputs[rid] = (names, types)
        return rid, types

    def setup_inputs(self, names: list[str]) -> tuple[int, list[str]]:
        self.send("I", ",".join(names).encode())
        rep = self.reply("I")
        rid, types = rep[0], rep[1:].decode().split(",")
        if rid:
            self.inputs[rid] = (names, types)
        return rid, types

    def start(self) -> bool:
        self.send("S")
        return self.reply("S")[0] == 1

    def pause(self) -> bool:
        self.send("P")
        return self.reply("P")[0] == 1

    # -- synchronisation loop -----------------------------------------------------------
    def write(self, rid: int, values: dict[str, Any]) -> None:
        names, types = self.inputs[rid]
        fmt = ">B" + "".join(GUIDE_FORMATS[t] for t in types)
        flat: list[Any] = [rid]
        for n in names:
            v = values[n]
            flat.extend(v if isinstance(v, list | tuple) else [v])
        self.send("U", struct.pack(fmt, *flat))

    def read(self) -> dict[str, Any]:
        """The next output data package, decoded with the setup reply's types."""
        payload = self.reply("U")
        if self.protocol >= 2:
            rid, data = payload[0], payload[1:]
        else:
            rid, data = next(iter(self.outputs)), payload
        names, types = self.outputs[rid]
        fmt = ">" + "".join(GUIDE_FORMATS[t] for t in types)
        if struct.calcsize(fmt) != len(data):
            raise ValueError(
                f"data package of {len(data)} bytes, the types say {struct.calcsize(fmt)}"
            )
        vals = list(struct.unpack(fmt, data))
        out: dict[str, Any] = {}
        for n, t in zip(names, types, strict=True):
            k = 6 if t.startswith("VECTOR6") else 3 if t == "VECTOR3D" else 1
            out[n] = vals[:k] if k > 1 else vals[0]
            vals = vals[k:]
        return out


def run_loop(
    sim: Any, text: str, reg: int, home: Any, timeout: float = 120.0
) -> tuple[list[int], Any, Any]:
    """Play the station for a fixed-loop program (``quickhealth plan``'s ``loop.script``).

    Puts the simulated arm at ``home``, sends ``text`` to the secondary interface (30002),
    and watches ``output_int_register_<reg>`` over RTDE: each pose index announced is
    acknowledged in ``input_int_register_<reg>``, with the actual joints and the reported TCP
    pose of that moment kept.  Returns (indices, joints (n, 6), TCP poses (n, 6)) once the
    program has stopped.
    """
    import numpy as np

    sim.request("set_q", q=[float(v) for v in home])
    seen: list[int] = []
    qs, tcps = [], []
    with RtdeGuideClient(sim.host) as g:
        if not g.request_protocol_version(2):
            raise RuntimeError("the controller refused RTDE protocol version 2")
        rid, types = g.setup_inputs([f"input_int_register_{reg}"])
        if not rid:
            raise RuntimeError(f"input register {reg} refused: {types}")
        names = ["timestamp", f"output_int_register_{reg}", "actual_q", "actual_TCP_pose"]
        g.setup_outputs([*names, "runtime_state"], 500.0)
        g.write(rid, {f"input_int_register_{reg}": 0})
        if not g.start():
            raise RuntimeError("the controller refused to start the RTDE stream")
        with socket.create_connection((sim.host, 30002), timeout=5) as s:
            s.sendall(text.encode())
        t0 = time.monotonic()
        started = False
        while time.monotonic() - t0 < timeout:
            d = g.read()
            started |= d["runtime_state"] == 2  # PLAYING
            k = d[f"output_int_register_{reg}"]
            if k > 0 and (not seen or seen[-1] != k):
                seen.append(k)
                qs.append(d["actual_q"])
                tcps.append(d["actual_TCP_pose"])
                g.write(rid, {f"input_int_register_{reg}": k})
            if started and d["runtime_state"] == 1:  # STOPPED
                break
    return seen, np.asarray(qs), np.asarray(tcps)
