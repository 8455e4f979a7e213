"""A technician's dashboard client: UR's dashboard server (port 29999) as a line protocol.

Used by the simulated-cell tests and the station soak to do what a technician does from the
pendant or a terminal (release a protective stop, power on, ask the robot model).  The
conformance suite keeps its own client: it asserts the banner and the replies to the byte."""

from __future__ import annotations

import socket

DASHBOARD_PORT = 29999  # fixed on every UR controller


def dashboard(host: str, *lines: str, timeout: float = 5.0) -> list[str]:
    """Send each command line in turn on one connection; returns the replies, stripped."""
    with socket.create_connection((host, DASHBOARD_PORT), timeout=timeout) as s:
        f = s.makefile("rwb", buffering=0)
        f.readline()  # the banner
        out = []
        for line in lines:
            f.write(line.encode() + b"\n")
            out.append(f.readline().decode().strip())
        return out
