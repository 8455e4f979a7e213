"""The dashboard server (29999): UR's command set for the reported software version.

Commands and replies follow UR's "Dashboard Server" documents, one for CB-Series (3.x)
and one for e-Series (5.x).  Each command in :data:`COMMANDS` names the first version of
each line that has it (``None``: that line has not); a command the reported version lacks
is answered as an unknown one: ``could not understand: '<line>'``.  Failures answer with
UR's words too (``Failed to execute: play``, ``File not found: x.urp``, ``Cannot unlock
protective stop until 5s after occurrence. …``).

Programs for ``load``: PolyScope saves each program as ``NAME.urp`` with its generated
URScript beside it, ``NAME.script``; the simulator loads ``NAME.urp`` from its programs
folder (``--programs DIR``) and, on ``play``, runs ``NAME.script`` with its URScript
interpreter (:mod:`.urscript_vm`).
"""

from __future__ import annotations

import os
import socket
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from ..hardware.urtypes import RobotMode, RuntimeState, SafetyMode
from . import urscript_program
from .controller import close_socket
from .wire import dashboard_model

if TYPE_CHECKING:
    from .controller import Controller

Version = tuple[int, ...]
Handler = Callable[["Controller", str], str]


@dataclass(frozen=True)
class Command:
    """One dashboard command: the first CB3 and e-Series versions that have it."""

    since_cb3: Version | None
    since_e: Version | None
    handler: Handler

    def available(self, version: Version) -> bool:
        since = self.since_cb3 if version[0] < 5 else self.since_e
        return since is not None and tuple(version[:3]) >= since


def _mode_name(mode: RobotMode) -> str:
    return {
        RobotMode.DISCONNECTED: "DISCONNECTED",
        RobotMode.CONFIRM_SAFETY: "CONFIRM_SAFETY",
        RobotMode.BOOTING: "BOOTING",
        RobotMode.POWER_OFF: "POWER_OFF",
        RobotMode.POWER_ON: "POWER_ON",
        RobotMode.IDLE: "IDLE",
        RobotMode.BACKDRIVE: "BACKDRIVE",
        RobotMode.RUNNING: "RUNNING",
    }.get(mode, "NO_CONTROLLER")


def _program_label(ctrl: Controller) -> str:
    if ctrl.runtime_state != RuntimeState.STOPPED or ctrl.loaded is None:
        return ctrl.program_name if ctrl.program_kind is not None else "<unnamed>"
    return os.path.basename(ctrl.loaded)


def _state_name(state: RuntimeState) -> str:
    return {RuntimeState.PLAYING: "PLAYING", RuntimeState.PAUSED: "PAUSED"}.get(state, "STOPPED")


def robot_model(ctrl: Controller) -> str:
    """``get robot model``: ``UR3``, ``UR5``, … (the e-Series answers without the ``e``)."""
    return dashboard_model((ctrl.arm.ik_model or ctrl.arm.robot).name)


def _load(ctrl: Controller, arg: str) -> str:
    if not arg:
        return "No program specified"
    folder = ctrl.programs_dir
    path = arg if os.path.isabs(arg) or folder is None else os.path.join(folder, arg)
    if folder is None or not arg.endswith(".urp") or not os.path.isfile(path):
        return f"File not found: {arg}"
    script = path[: -len(".urp")] + ".script"
    if not os.path.isfile(script):
        return f"Error while loading program: {arg}"
    with ctrl.lock:
        if ctrl.runtime_state != RuntimeState.STOPPED:
            ctrl.stop_program()
        ctrl.loaded = path
    return f"Loading program: {arg}"


def _play(ctrl: Controller, _: str) -> str:
    with ctrl.lock:
        if ctrl.runtime_state == RuntimeState.PAUSED:
            return "Starting program" if ctrl.resume_program() else "Failed to execute: play"
        if ctrl.runtime_state == RuntimeState.PLAYING or ctrl.loaded is None:
            return "Failed to execute: play"
        if not ctrl.can_move():
            return "Failed to execute: play"
        path = ctrl.loaded
    try:
        with open(path[: -len(".urp")] + ".script", encoding="utf-8") as f:
            text = f.read(1_000_000)
    except OSError:
        return "Failed to execute: play"
    urscript_program.run(ctrl, text, "dashboard")
    return (
        "Starting program"
        if ctrl.runtime_state == RuntimeState.PLAYING
        else "Failed to execute: play"
    )


def _stop(ctrl: Controller, _: str) -> str:
    # "Stopped" also when nothing runs: ur-rtde's control interface stops its own script,
    # then sends ``stop`` and raises on any other reply, and it works with real controllers.
    ctrl.note_stop("dashboard")
    ctrl.stop_program()
    return "Stopped"


def _pause(ctrl: Controller, _: str) -> str:
    ctrl.note_stop("dashboard pause")
    return "Pausing program" if ctrl.pause_program() else "Failed to execute: pause"


def _unlock(ctrl: Controller, _: str) -> str:
    out = ctrl.unlock_protective_stop()
    if out == "ok":
        return "Protective stop releasing"
    return (
        "Cannot unlock protective stop until 5s after occurrence. Always inspect cause of "
        "protective stop before unlocking"
    )


def _power(ctrl: Controller, arg: str) -> str:
    if arg == "on":
        ctrl.power_on()
        return "Powering on"
    ctrl.power_off()
    return "Powering off"


def _brake_release(ctrl: Controller, _: str) -> str:
    ctrl.brake_release()
    return "Brake releasing"


def _version(ctrl: Controller, _: str) -> str:
    v = ctrl.version
    return f"URSoftware {v[0]}.{v[1]}.{v[2]}.{v[3]} (quickhealth simulator)"


def _close_popup(ctrl: Controller, _: str) -> str:
    with ctrl.lock:
        ctrl.popup_text = None
    return "closing popup"


def _add_to_log(ctrl: Controller, arg: str) -> str:
    if not arg:
        return "No log message to add"
    ctrl.say(f"log: {arg}")
    return "Added log message"


def _popup(ctrl: Controller, arg: str) -> str:
    with ctrl.lock:
        ctrl.popup_text = arg
    return "showing popup"


def _restart_safety(ctrl: Controller, _: str) -> str:
    ctrl.restart_safety()
    return "Restarting safety"


def _shutdown(ctrl: Controller, _: str) -> str:
    ctrl.power_off()
    return "Shutting down"


def _saved(ctrl: Controller, _: str) -> str:
    if ctrl.loaded is None:
        return "false <unnamed>"
    return f"true {os.path.basename(ctrl.loaded)}"


def _safety(word: str) -> Handler:
    def run(ctrl: Controller, _: str) -> str:
        m = ctrl.safety_mode
        name = m.name if m != SafetyMode.UNKNOWN else "FAULT"
        return f"{word}: {name}"

    return run


def _user_role(ctrl: Controller, arg: str) -> str:
    roles = ("programmer", "operator", "none", "locked", "restricted")
    if arg.lower() not in roles:
        return f"Failed setting user role: {arg}"
    return f"Setting user role: {arg}"


def _operational_mode(ctrl: Controller, arg: str) -> str:
    if arg.lower() not in ("manual", "automatic"):
        return f"Failed setting operational mode: {arg}"
    return f"Operational mode '{arg.lower()}' is set"


def _const(text: str) -> Handler:
    return lambda ctrl, arg: text


_ALL = (3, 0, 0)
_E = (5, 0, 0)
COMMANDS: dict[str, Command] = {
    "load": Command(_ALL, _E, _load),
    "play": Command(_ALL, _E, _play),
    "stop": Command(_ALL, _E, _stop),
    "pause": Command(_ALL, _E, _pause),
    "shutdown": Command(_ALL, _E, _shutdown),
    "running": Command(
        _ALL,
        _E,
        lambda c, a: f"Program running: {str(c.runtime_state == RuntimeState.PLAYING).lower()}",
    ),
    "robotmode": Command(_ALL, _E, lambda c, a: f"Robotmode: {_mode_name(c.robot_mode)}"),
    "get loaded program": Command(
        _ALL,
        _E,
        lambda c, a: f"Loaded program: {c.loaded}" if c.loaded else "No program loaded",
    ),
    "popup": Command(_ALL, _E, _popup),
    "close popup": Command(_ALL, _E, _close_popup),
    "addtolog": Command(_ALL, _E, _add_to_log),
    "setuserrole": Command((3, 0, 0), None, _user_role),
    "isprogramsaved": Command((3, 0, 0), _E, _saved),
    "programstate": Command(
        _ALL, _E, lambda c, a: f"{_state_name(c.runtime_state)} {_program_label(c)}"
    ),
    "polyscopeversion": Command(_ALL, _E, _version),
    "power on": Command((3, 0, 0), _E, lambda c, a: _power(c, "on")),
    "power off": Command((3, 0, 0), _E, lambda c, a: _power(c, "off")),
    "brake release": Command((3, 0, 0), _E, _brake_release),
    "safetymode": Command((3, 0, 0), _E, _safety("Safetymode")),
    "unlock protective stop": Command((3, 1, 0), _E, _unlock),
    "close safety popup": Command((3, 1, 0), _E, _const("closing safety popup")),
    "load installation": Command((3, 2, 0), _E, lambda c, a: f"File not found: {a}"),
    "restart safety": Command((3, 7, 0), (5, 1, 0), _restart_safety),
    "safetystatus": Command((3, 11, 0), (5, 4, 0), _safety("Safetystatus")),
    "get serial number": Command((3, 12, 0), (5, 6, 0), _const("20185500001")),
    "get robot model": Command((3, 12, 0), (5, 6, 0), lambda c, a: robot_model(c)),
    "get operational mode": Command(None, (5, 6, 0), _const("NONE")),
    "set operational mode": Command(None, (5, 0, 0), _operational_mode),
    "clear operational mode": Command(
        None,
        (5, 0, 0),
        _const(
            "No longer controlling the operational mode. Current operational mode: 'automatic'."
        ),
    ),
    "is in remote control": Command(None, (5, 6, 0), _const("true")),
    "generate flight report": Command((3, 13, 0), (5, 8, 0), _const("Flight report generated")),
}
# Commands whose argument follows the command word(s) after a space.
_WITH_ARGUMENT = (
    "load installation",
    "load",
    "popup",
    "addtolog",
    "setuserrole",
    "set operational mode",
)


def parse(line: str) -> tuple[str, str]:
    """``(command, argument)`` of a line: the command lower-cased, the argument as sent."""
    low = line.lower()
    for name in _WITH_ARGUMENT:
        if low == name or low.startswith(name + " "):
            return name, line[len(name) :].strip()
    return low.strip(), ""


def answer(ctrl: Controller, line: str) -> str:
    """The reply to one dashboard line (without the newline)."""
    if len(line) > 1024:
        return "could not understand: command too long"
    name, arg = parse(line)
    cmd = COMMANDS.get(name)
    if cmd is None or not cmd.available(ctrl.version):
        return f"could not understand: '{line[:80]}'"
    return cmd.handler(ctrl, arg)


def session(ctrl: Controller, conn: socket.socket) -> None:
    """The dashboard server's session on one connection (line protocol)."""
    f = conn.makefile("rwb", buffering=0)
    try:
        f.write(b"Connected: Universal Robots Dashboard Server\n")
        for raw in f:
            line = raw.decode("ascii", "replace").strip()
            if line.lower() == "quit":
                f.write(b"Disconnected\n")
                break
            f.write((answer(ctrl, line) + "\n").encode())
    except OSError:
        pass
    finally:
        close_socket(conn)
