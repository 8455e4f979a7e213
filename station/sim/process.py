"""The simulator as a process: start it, drive it over its control port, its command line.

The ur-rtde constructors hold the GIL, so the simulator never runs as a thread of the
process that uses the client (``notes/ur-rtde.md``): :func:`start_sim_controller` starts
``python -m quickhealth.station.sim`` and returns a :class:`SimControllerHandle`.
"""

from __future__ import annotations

import argparse
import errno
import fcntl
import json
import math
import os
import socket
import stat
import subprocess
import sys
import threading
import time
from typing import Any

import numpy as np

from ...identify.errors import HardwareError, InputError
from ..planning.cell import load_cell
from . import __doc__ as package_doc
from .arm import HOME_Q_DEG, Arm, controller_arm
from .controller import Controller, close_socket
from .kinematics import calibration_from_yaml, factory_calibration
from .primary import PRIMARY_PORT, SECONDARY_PORT
from .servers import serve, shutdown
from .states import Delays
from .wire import (
    CB3_VERSION,
    CONTROL_PORT,
    DASHBOARD_PORT,
    HOST,
    RTDE_PORT,
    SCRIPT_PORT,
    check_loopback,
    max_stream_hz,
    parse_version,
    version_for,
)

PORT_LOCK = "/tmp/quickhealth-ur-ports-{host}.lock"
# The UR ports are fixed (the ur-rtde client hard-codes them), so two simulators on one host
# need two addresses: every address of 127.0.0.0/8 is loopback on Linux.  A simulator started
# without an address takes the first free one of these.
LOOPBACK_POOL = tuple(f"127.0.0.{n}" for n in range(1, 255))
# The smart target on the flange (plate, pan motor, bracket): the real arm's payload, which
# the controller is not told about unless a program calls set_payload.  An estimate.
SMART_TARGET_KG = 0.6
SMART_TARGET_COM = (0.0, 0.0, 0.05)


class SimControllerHandle:
    """A running simulator process, driven over its loopback control port.

    Examples
    --------
    >>> sim = start_sim_controller()                       # doctest: +SKIP
    >>> sim.fault("protective_stop", after_moves=3)        # doctest: +SKIP
    >>> sim.fault("restart", down_s=2.0)                   # doctest: +SKIP
    >>> sim.stop()                                         # doctest: +SKIP
    """

    def __init__(self, proc: Any, control_port: int, port_lock: int = -1, host: str = HOST) -> None:
        self.proc = proc
        self.host = host  # the loopback address of its UR ports: connect the client here
        self.control_port = control_port
        self._port_lock = port_lock
        self._sock: socket.socket | None = None
        self._file: Any = None
        self._lock = threading.Lock()

    def request(self, cmd: str, **kw: Any) -> dict[str, Any]:
        """Send one control request and return the decoded answer (raises on error)."""
        with self._lock:
            if self._sock is None:
                self._sock = socket.create_connection((self.host, self.control_port), timeout=5.0)
                self._file = self._sock.makefile("rwb", buffering=0)
            self._file.write((json.dumps({"cmd": cmd, **kw}) + "\n").encode())
            line = self._file.readline()
        if not line:
            raise ConnectionError("simulator control channel closed")
        out: dict[str, Any] = json.loads(line)
        if not out.get("ok"):
            raise ValueError(out.get("error", "simulator refused the request"))
        return out

    def fault(self, kind: str, **when: Any) -> None:
        """Inject a fault now, ``after_s=`` seconds or ``after_moves=`` motion commands.

        Kinds: ``protective_stop``, ``emergency_stop``, ``program_stop``, ``freeze_stream``,
        ``drop_connection`` (``refuse=False`` to accept reconnections at once), ``restart``
        (``down_s=``, default 2 s), ``slow_program_start`` (``delay_s=``) and ``clear``.
        """
        self.request("fault", kind=kind, **when)

    def truth(self) -> tuple[np.ndarray, np.ndarray]:
        """Actual joints (rad) and the true target frame at pan 0, ``T_instr_target0``, now."""
        out = self.request("truth")
        return np.asarray(out["q"]), np.asarray(out["T_instr_target0"])

    def twin_truth(self) -> dict[str, Any]:
        """The digital twin's truth document (``TwinTruth.to_dict``)."""
        return self.request("twin")["truth"]

    def state(self) -> dict[str, Any]:
        """Modes, joints, whether the arm moves or a path is being planned."""
        return self.request("state")

    def stop(self, timeout: float = 5.0) -> None:
        """Shut the simulator down and reap the process."""
        try:
            self.request("shutdown")
        except (OSError, ValueError):
            pass
        if self._sock is not None:
            close_socket(self._sock)
            self._sock = None
        if self.proc is not None:
            try:
                self.proc.wait(timeout=timeout)
            except Exception:  # noqa: BLE001 - last resort: the process did not exit in time
                self.proc.kill()
                self.proc.wait(timeout=timeout)
            self.proc = None
        if self._port_lock >= 0:
            os.close(self._port_lock)  # releases the host-wide port lock
            self._port_lock = -1

    def __enter__(self) -> SimControllerHandle:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def _port_lock(host: str) -> int:
    """A descriptor of ``host``'s port lock file, opened without following a link (made with
    ``O_EXCL``; shared by every user of the machine, since the ports are).  Only ``flock``ed,
    never written, so read-only is enough.  -1 when another user's file there cannot be read
    (that address counts as taken).

    Raises
    ------
    HardwareError
        A link, a pipe or another non-regular file stands there (planted: one line).
    """
    path = PORT_LOCK.format(host=host)
    flags = os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC
    try:
        try:
            fd = os.open(path, flags | os.O_CREAT | os.O_EXCL, 0o644)
        except FileExistsError:
            fd = os.open(path, flags)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise HardwareError(
                f"{path}: a symbolic link stands where the simulator's port lock goes: "
                "refusing to follow it (planted by someone?); remove it"
            ) from None
        if exc.errno == errno.EACCES:
            return -1
        raise HardwareError(f"{path}: cannot open the port lock: {exc.strerror}") from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise HardwareError(f"{path}: the port lock is not a plain file; remove it")
    return fd


def _try_address(host: str) -> int:
    """The lock of ``host``'s UR ports (an open descriptor), or -1 when another simulator
    holds it or something else listens there."""
    fd = _port_lock(host)
    if fd < 0:
        return -1
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        return -1
    if not ports_free(host):
        os.close(fd)
        return -1
    return fd


def _take_address(
    host: str | None, wait_s: float, skip: set[str] | frozenset[str] = frozenset()
) -> tuple[str, int]:
    """A loopback address whose UR ports are free, and its lock (held until the simulator
    stops).  ``host`` given: wait up to ``wait_s`` for that one; else the first free one
    not in ``skip``."""
    pool = (
        (check_loopback(host),)
        if host is not None
        else tuple(h for h in LOOPBACK_POOL if h not in skip)
    )
    deadline = time.monotonic() + wait_s
    while True:
        for h in pool:
            fd = _try_address(h)
            if fd >= 0:
                return h, fd
        if time.monotonic() > deadline:
            where = pool[0] if host is not None else "any loopback address"
            raise HardwareError(
                f"UR ports 30004/29999/30003 on {where} are in use by another simulator "
                f"or controller (waited {wait_s:.0f} s)"
            )
        time.sleep(0.1)


def ports_free(host: str = HOST) -> bool:
    """True when the fixed UR ports are free on ``host``."""
    for port in (RTDE_PORT, DASHBOARD_PORT, SCRIPT_PORT, PRIMARY_PORT, SECONDARY_PORT):
        s = socket.socket()
        try:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind((host, port))
        except OSError:
            return False
        finally:
            s.close()
    return True


def start_sim_controller(
    *,
    control_port: int = CONTROL_PORT,
    q0_deg: list[float] | None = None,
    twin_seed: int = 1,
    cell: str = "reference",
    timeout: float = 15.0,
    verbose: bool = False,
    speed_factor: float = 1.0,
    wait_s: float = 120.0,
    degrade: dict[str, float] | None = None,
    controller_version: str | None = None,
    host: str | None = None,
    calibration: str | None = None,
    delays: str | None = None,
    powered_off: bool = False,
    programs: str | None = None,
    payload_kg: float | None = None,
    pick_place_kg: float | None = None,
) -> SimControllerHandle:
    """Start the simulator as a separate process and wait until it answers.

    The ur-rtde constructors hold the GIL, so the simulator must never run as a thread of
    the process that uses the client.  The UR ports are fixed, so each simulator takes its
    own loopback address (``host``, or the first free one of 127.0.0.1 … 127.0.0.254, held
    by a lock file until it stops): simulators started by different programs at once never
    meet.  Connect the client to :attr:`SimControllerHandle.host`.  With ``host`` given,
    wait up to ``wait_s`` seconds for that address to become free.
    ``controller_version`` (``"5.11.1"``) makes it report that version (major 5: an
    e-Series controller, which streams at 500 Hz); the default is the version of the cell's
    arm: 3.15.7 (125 Hz) for a CB3 arm, 5.11.1 (500 Hz) for an e-Series one.
    ``calibration``: the controller's kinematics (``--calibration``: ``factory``,
    ``factory:SEED``, ``nominal`` or a UR calibration YAML); ``delays``: its state-machine
    delays (``--delays``, e.g. ``boot=0.2,brake_release=0.2,unlock_after=0.3``);
    ``powered_off``: start with the arm off; ``programs``: the folder ``load`` finds programs
    in; ``payload_kg``: the real payload (default: the cell's smart target);
    ``pick_place_kg``: the arm picks and places parts of up to this mass between moves
    (:meth:`~.controller.Controller.pick_and_place`).

    Raises
    ------
    HardwareError
        The ports are taken (another simulator or a controller on this host) or the process
        did not come up within ``timeout`` seconds.
    """
    if controller_version is not None:
        parse_version(controller_version)  # ValueError before anything starts
    args = [
        "--control-port",
        str(control_port),
        "--twin-seed",
        str(twin_seed),
        "--cell",
        cell,
        "--speed-factor",
        str(speed_factor),
        "--parent-pid",
        str(os.getpid()),
    ]
    if q0_deg is not None:
        args += ["--q0-deg", ",".join(f"{v:.9g}" for v in q0_deg)]
    if degrade:
        args += ["--degrade", ",".join(f"{k}={v:.12g}" for k, v in degrade.items())]
    if controller_version is not None:
        args += ["--controller-version", controller_version]
    if calibration is not None:
        args += ["--calibration", calibration]
    if delays is not None:
        Delays.parse(delays)  # ValueError before anything starts
        args += ["--delays", delays]
    if powered_off:
        args.append("--powered-off")
    if programs is not None:
        args += ["--programs", programs]
    if payload_kg is not None:
        args += ["--payload-kg", f"{payload_kg:.9g}"]
    if pick_place_kg:
        args += ["--pick-place-kg", f"{pick_place_kg:.9g}"]
    if verbose:
        args.append("--verbose")
    tried: set[str] = set()
    while True:
        addr, lock = _take_address(host, wait_s, skip=tried)
        proc = subprocess.Popen(
            [sys.executable, "-m", "quickhealth.station.sim", *args, "--host", addr],
            stdin=subprocess.DEVNULL,
        )
        handle = SimControllerHandle(proc, control_port, lock, addr)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and proc.poll() is None:
            try:
                handle.request("ping")
                return handle
            except OSError:
                time.sleep(0.05)
        code = proc.poll()
        handle.stop(timeout=1.0)
        if code == 3 and host is None:
            # It could not listen: something that does not take our lock files (another
            # tool's simulator) holds that address.  Try the next one.
            tried.add(addr)
            continue
        if code is not None:
            raise HardwareError(f"controller simulator exited at start (status {code})")
        raise HardwareError(f"controller simulator did not answer within {timeout:.0f} s")


def build_controller(
    *,
    control_port: int = CONTROL_PORT,
    q0_deg: list[float] | None = None,
    twin_seed: int = 1,
    cell: str = "reference",
    verbose: bool = False,
    degrade: dict[str, float] | None = None,
    version: tuple[int, int, int, int] | None = None,
    host: str = HOST,
    calibration: str = "factory",
    delays: Delays | None = None,
    payload_kg: float | None = None,
) -> Controller:
    """A controller whose arm is the digital twin of ``twin_seed`` placed in ``cell``.

    The controller plans and reports with its own kinematics: the cell's arm as its
    controller knows it (:func:`~.arm.controller_arm`: its nominal kinematics, its own joint
    limits and speeds, no payload) under a factory calibration (``calibration``: ``factory``
    seeded by the twin seed, ``factory:SEED``, ``nominal`` for none, or a UR calibration
    YAML), different from nominal and from the twin's true arm.  The arm carries
    ``payload_kg`` (default: the cell's smart target, ``[target] mass_kg``, else
    :data:`SMART_TARGET_KG`) that the controller is not told about.  ``version``: the software
    version reported, by default that of the arm's controller generation.

    Raises
    ------
    InputError
        A calibration that is none of these, or a YAML file that cannot be read.
    """
    from .world import build_world  # the simulated world: OpenCV and the twin, in the child

    c = load_cell(cell)
    world = build_world(cell, twin_seed=twin_seed, degrade=degrade)
    nominal = controller_arm(c.robot)  # the bare arm: the twin's robot carries the target
    if calibration == "nominal":
        model = nominal
    elif calibration == "factory" or calibration.startswith("factory:"):
        seed_text = calibration.partition(":")[2] or str(twin_seed)
        try:
            seed = int(seed_text)
        except ValueError:
            raise InputError(
                f"--calibration factory:SEED needs an integer seed, got {seed_text!r}"
            ) from None
        model = factory_calibration(nominal, seed)
    else:
        model = calibration_from_yaml(nominal, calibration)
    q0 = np.radians(q0_deg if q0_deg is not None else HOME_Q_DEG)
    version = version_for(nominal.controller) if version is None else version
    if payload_kg is None:
        payload_kg = c.target_mass if c.target_mass > 0.0 else SMART_TARGET_KG
    com = (
        tuple(map(float, c.target_com))
        if c.target_mass > 0.0 and c.target_com is not None
        else SMART_TARGET_COM
    )
    arm = Arm(model, q0, truth=world.T_instr_target0, ik_model=nominal)
    ctrl = Controller(
        arm,
        control_port=control_port,
        verbose=verbose,
        version=version,
        host=host,
        delays=delays,
        payload_kg=payload_kg,
        payload_com=com,
    )
    ctrl.world = world
    return ctrl


def main(argv: list[str] | None = None) -> int:
    """Command line of the simulator process."""
    p = argparse.ArgumentParser(
        prog="quickhealth sim-controller",
        description=package_doc,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_arguments(p)
    args = p.parse_args(argv)
    return run_from_args(args)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options shared by ``quickhealth sim-controller`` and ``python -m``."""
    p.add_argument(
        "--control-port",
        type=int,
        default=CONTROL_PORT,
        help="loopback port of the JSON control channel (default %(default)s)",
    )
    p.add_argument(
        "--host",
        default=HOST,
        help="loopback address to serve on, 127.x.y.z (default %(default)s)",
    )
    p.add_argument("--q0-deg", default=None, help="start joints, comma-separated degrees")
    p.add_argument(
        "--twin-seed",
        type=int,
        default=1,
        help="seed of the digital twin whose errors the arm has (default %(default)s)",
    )
    p.add_argument("--cell", default="reference", help="cell name or file (camera placement)")
    p.add_argument(
        "--degrade",
        default=None,
        help="change the twin's true errors, e.g. j2.ex.c0=5e-4 (m or rad; comma-separated)",
    )
    p.add_argument(
        "--controller-version",
        default=None,
        help="controller software version reported to clients; major 3 = CB3 (RTDE at "
        "125 Hz), 5 = e-Series (500 Hz), e.g. 5.11.1 (default: the cell's arm's, "
        f"{'.'.join(map(str, CB3_VERSION[:3]))} for a CB3, 5.11.1 for an e-Series)",
    )
    p.add_argument(
        "--calibration",
        default="factory",
        help="the controller's kinematics: factory (a simulated factory calibration seeded by "
        "the twin seed), factory:SEED, nominal (the published DH table) or a UR calibration "
        "YAML file (default %(default)s)",
    )
    p.add_argument(
        "--delays",
        default=None,
        help="state-machine delays in s, e.g. boot=3,power_on=1.5,brake_release=2,"
        f"unlock_after=5 (default: {Delays().spec()})",
    )
    p.add_argument(
        "--powered-off",
        action="store_true",
        help="start with the arm powered off (dashboard: power on, brake release)",
    )
    p.add_argument("--programs", default=None, help="folder the dashboard's load finds programs in")
    p.add_argument(
        "--payload-kg",
        type=float,
        default=None,
        help="the arm's real payload, kg (the controller's model has none until set_payload; "
        f"default the cell's smart target, else {SMART_TARGET_KG})",
    )
    p.add_argument(
        "--pick-place-kg",
        type=float,
        default=0.0,
        help="the arm picks and places parts of up to this mass (kg) between moves: a payload "
        "that changes between poses, in the joint torques (default 0: none)",
    )
    p.add_argument("--verbose", action="store_true", help="log controller events to stderr")
    p.add_argument(
        "--speed-factor",
        type=float,
        default=1.0,
        help="run every motion this many times faster (tests; default %(default)s)",
    )
    p.add_argument(
        "--parent-pid",
        type=int,
        default=0,
        help="exit when this process is gone (set by start_sim_controller)",
    )


def _watch_parent(ctrl: Controller, pid: int) -> None:
    """Shut down when the process that started the simulator dies (e.g. ``kill -9``)."""
    while not ctrl.stop_event.wait(0.2):
        if os.getppid() != pid:
            ctrl.say("parent process gone: shutting down")
            shutdown(ctrl)
            return


def run_from_args(args: argparse.Namespace) -> int:
    """Build and serve; returns the exit status."""
    q0 = None
    if args.q0_deg:
        try:
            q0 = [float(v) for v in args.q0_deg.split(",")]
        except ValueError:
            q0 = None
        if q0 is None or len(q0) != 6 or not all(math.isfinite(v) for v in q0):
            sys.stderr.write("quickhealth: error: --q0-deg needs 6 comma-separated numbers\n")
            return 2
    if not (0.1 <= args.speed_factor <= 100.0):
        sys.stderr.write("quickhealth: error: --speed-factor must be in 0.1..100\n")
        return 2
    if not 1024 <= args.control_port <= 65535:
        sys.stderr.write("quickhealth: error: --control-port must be in 1024..65535\n")
        return 2
    try:
        given = getattr(args, "controller_version", None)
        version = None if given is None else parse_version(given)
    except ValueError as exc:
        sys.stderr.write(f"quickhealth: error: --controller-version: {exc}\n")
        return 2
    try:
        host = check_loopback(getattr(args, "host", HOST))
    except ValueError as exc:
        sys.stderr.write(f"quickhealth: error: --host: {exc}\n")
        return 2
    from .world import parse_degradation  # (the same)

    try:
        delays = Delays.parse(getattr(args, "delays", None))
    except ValueError as exc:
        sys.stderr.write(f"quickhealth: error: --delays: {exc}\n")
        return 2
    payload = getattr(args, "payload_kg", None)
    if payload is not None and not (math.isfinite(payload) and 0.0 <= payload <= 100.0):
        sys.stderr.write("quickhealth: error: --payload-kg must be in 0..100\n")
        return 2
    part = float(getattr(args, "pick_place_kg", 0.0) or 0.0)
    if not (math.isfinite(part) and 0.0 <= part <= 100.0):
        sys.stderr.write("quickhealth: error: --pick-place-kg must be in 0..100\n")
        return 2
    try:
        degrade = parse_degradation(getattr(args, "degrade", None))
        ctrl = build_controller(
            control_port=args.control_port,
            q0_deg=q0,
            twin_seed=args.twin_seed,
            cell=args.cell,
            verbose=args.verbose,
            degrade=degrade,
            version=version,
            host=host,
            calibration=getattr(args, "calibration", "factory"),
            delays=delays,
            payload_kg=payload,
        )
    except InputError as exc:
        sys.stderr.write(f"quickhealth: error: {exc}\n")
        return 2
    ctrl.speed_factor = float(args.speed_factor)
    ctrl.pick_and_place(part)
    ctrl.programs_dir = getattr(args, "programs", None)
    if getattr(args, "powered_off", False):
        ctrl.power.power_off()
    # The stream threads wake every 2-8 ms; let them take the GIL from the planner quickly.
    sys.setswitchinterval(0.0005)
    ctrl.say(
        f"{ctrl.arm.robot.name} controller version {'.'.join(map(str, ctrl.version))}, "
        f"RTDE up to {max_stream_hz(ctrl.version):.0f} Hz"
    )
    if args.parent_pid:
        threading.Thread(target=_watch_parent, args=(ctrl, args.parent_pid), daemon=True).start()
    try:
        serve(ctrl)
    except OSError as exc:
        sys.stderr.write(f"quickhealth: error: {exc}\n")
        return 3
    except KeyboardInterrupt:
        return 0
    return 0
