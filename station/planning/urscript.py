"""URScript of the fixed loop, from a validated :class:`~.planfile.Plan` and fixed templates.

Nothing from a file reaches the program as text: joint targets, speeds and times are
re-formatted from floats checked finite (``%.9f``), register numbers and counts from checked
integers, the hash from its checked hex digits, and pose names (identifiers only) appear in
comments after a second check here.  Structure (docs/plan.md)::

    def quickhealth_loop():
      set_tcp(p[...])                      # TCP = smart target centre (moveL is straight there)
      def qh_measure(index): ...           # settle, announce the pose, wait for the station
      (halt unless the arm is at the home position the first leg was checked from)
      movej(q1, a, v)                      # first pose
      while qh_pass < passes:
        qh_measure(1)
        movel(q2, a, v) / movej(q2, a, v)  # one leg per pose, as planned
        qh_measure(2)
        ...
        (return leg to pose 1 when another pass follows)
      end
    end

``movel`` is given joint targets: the controller moves the TCP on a straight line to the
pose those joints reach, and ends in exactly that configuration.
"""

from __future__ import annotations

import math
import re

import numpy as np

from ...identify.errors import InputError
from ...identify.transforms import log_so3
from ..hardware.legs import Leg
from .planfile import HASH_RE, NAME_RE, Plan

HOME_TOLERANCE_RAD = 0.05  # how far from home (per joint) the program refuses to start


def _f(x: float) -> str:
    x = float(x)
    if not math.isfinite(x):
        raise InputError(f"URScript: non-finite number {x!r} refused")
    s = f"{x:.9f}"
    return "0.000000000" if s == "-0.000000000" else s


def _i(x: int, lo: int, hi: int) -> str:
    if isinstance(x, bool) or not isinstance(x, int) or not lo <= x <= hi:
        raise InputError(f"URScript: integer {x!r} outside [{lo}, {hi}] refused")
    return str(x)


def _q(q: np.ndarray) -> str:
    return "[" + ", ".join(_f(v) for v in q) + "]"


def _name(n: str) -> str:
    if not isinstance(n, str) or not NAME_RE.fullmatch(n):
        raise InputError(f"URScript: pose name {str(n)[:40]!r} refused (identifiers only)")
    return n


def render_urscript(plan: Plan) -> str:
    """The URScript program text of ``plan``'s loop (see module docstring)."""
    if not HASH_RE.fullmatch(plan.hash):
        raise InputError("URScript: plan hash is malformed")
    hexd = plan.hash.split(":", 1)[1]
    m = plan.motion
    jv, ja = _f(m.joint_speed), _f(m.joint_accel)
    lv, la = _f(m.linear_speed), _f(m.linear_accel)
    T = plan.T_flange_target
    rv = log_so3(T[:3, :3])
    tcp = "p[" + ", ".join(_f(v) for v in (*T[:3, 3], *rv)) + "]"
    reg = _i(m.handshake_register, 0, 47)
    k = len(plan.poses)
    _i(k, 1, 100000)
    cell = plan.cell_name if re.fullmatch(r"[A-Za-z0-9_\-]{1,64}", plan.cell_name) else "?"

    def move(leg: Leg, q: np.ndarray) -> str:
        if leg == Leg.LINEAR:
            return f"movel({_q(q)}, a={la}, v={lv})"
        return f"movej({_q(q)}, a={ja}, v={jv})"

    L = [
        "# quickhealth fixed-loop measurement program (docs/plan.md)",
        f"# plan sha256:{hexd}",
        f"# cell {cell}, {k} poses, {m.passes} pass(es); joints in rad, speeds in rad/s or m/s",
        "def quickhealth_loop():",
        f"  set_tcp({tcp})",
        f'  textmsg("quickhealth plan sha256:{hexd}")',
        "  def qh_measure(index):",
        "    # hold still for the settle time, then tell the station which pose is reached",
        f"    sleep({_f(m.settle_s)})",
    ]
    if m.handshake_register:
        L += [
            f"    write_output_integer_register({reg}, index)",
            "    qh_t = 0.0",
            f"    while read_input_integer_register({reg}) != index:",
            "      sync()",
            "      qh_t = qh_t + get_steptime()",
            f"      if qh_t > {_f(m.measure_timeout_s)}:",
            '        textmsg("quickhealth: no measurement acknowledgement at pose ", index)',
            "        halt",
            "      end",
            "    end",
        ]
    L.append("  end")
    if plan.home is not None:
        L += [
            "  # the loop was checked from the home position: refuse to start anywhere else",
            f"  qh_home = {_q(plan.home)}",
            "  qh_now = get_actual_joint_positions()",
            "  qh_j = 0",
            "  while qh_j < 6:",
            f"    if norm(qh_now[qh_j] - qh_home[qh_j]) > {_f(HOME_TOLERANCE_RAD)}:",
            '      textmsg("quickhealth: move the robot to the home position first")',
            "      halt",
            "    end",
            "    qh_j = qh_j + 1",
            "  end",
        ]
    L += [
        f"  # {_name(plan.poses[0].name)}: first pose",
        "  " + move(Leg.JOINT, plan.poses[0].q),
    ]
    L += ["  qh_pass = 0", f"  while qh_pass < {_i(m.passes, 1, 100)}:"]
    for j, p in enumerate(plan.poses):
        if j > 0:
            L.append(f"    # {_name(p.name)}: {p.leg.value} leg")
            L.append("    " + move(p.leg, p.q))
        L.append(f"    qh_measure({_i(p.index, 1, 100000)})")
    L += [
        "    qh_pass = qh_pass + 1",
        f"    if qh_pass < {_i(m.passes, 1, 100)}:",
        f"      # return leg to {_name(plan.poses[0].name)}: {plan.return_leg.value}",
        "      " + move(plan.return_leg, plan.poses[0].q),
        "    end",
        "  end",
    ]
    if m.handshake_register:
        L.append(f"  write_output_integer_register({reg}, -1)")
    L += ['  textmsg("quickhealth loop done")', "end", ""]
    return "\n".join(L)
