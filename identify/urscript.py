"""URScript joint targets: one tokenizer, shared by ``predict`` and ``compensate``.

A pure reader of a program's *text* (no files): it knows comments (``#`` to the end of the
line), string literals (``"…"`` and ``'…'`` with backslash escapes), brackets nested to any
depth, and whitespace or comments between a function name and its ``(``.  Every motion
command of the URScript manual is known (:data:`MOTIONS`).  A move to a target
(:data:`TARGET_MOVES`: ``movej``, ``movel``, ``movep``, ``movec``, ``servoj``, ``servoc``,
``optimovej``, ``optimovel``) whose target argument is a literal joint list ``[q1, …, qN]``
(numbers in rad, an optional sign each) is a *readable* target; ``movec`` has two, its via
point and its end point, in that order.  Every other target -- a variable, a pose literal
``p[…]``, an expression, a list of the wrong length -- and every motion without a joint
target (:data:`UNTARGETED_MOTIONS`: ``speedj``, ``speedl``, ``force_mode`` …) is
*unreadable*, reported with its line and column and never guessed or skipped: the robot
would otherwise move where nobody compensated, and every later approach direction would be
taken as if that move had not happened.  Text inside comments and strings is never a target.

SYNOPSIS::

    t = joint_targets(text, n_joints=6)
    t.q, t.lines, t.spans          # readable targets (rad), their lines, their list contents
    t.unreadable                   # (line, column, command, why) of every other motion
    new_text = replace_targets(text, t.spans, q_new)
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import InputError

F = NDArray[np.float64]

#: Moves to a target given as their first argument (``movec``: via and end point, the first
#: two); a literal joint list there is rewritten by ``compensate``.
TARGET_MOVES = ("movej", "movel", "movep", "movec", "servoj", "servoc", "optimovej", "optimovel")
#: Motions that take the arm somewhere without a joint target to rewrite (speeds, forces,
#: hand guiding, offsets and conveyor tracking added to the path).
UNTARGETED_MOTIONS = (
    "speedj",
    "speedl",
    "force_mode",
    "freedrive_mode",
    "teach_mode",
    "path_offset_enable",
    "path_offset_set",
    "track_conveyor_linear",
    "track_conveyor_circular",
    "screw_driving",
)
MOTIONS = TARGET_MOVES + UNTARGETED_MOTIONS
MOVES = TARGET_MOVES  # the name earlier versions exported

_TOKEN = re.compile(
    r"""
    (?P<ws>[ \t\r\f\v]+)
  | (?P<nl>\n)
  | (?P<comment>\#[^\n]*)
  | (?P<string>"(?:[^"\\\n]|\\.)*"|'(?:[^'\\\n]|\\.)*')
  | (?P<number>(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)
  | (?P<name>[A-Za-z_][A-Za-z0-9_]*)
  | (?P<op>==|!=|<=|>=|[-+*/%<>=,:()\[\]{}.;!&|^~@$?\\`])
    """,
    re.VERBOSE,
)
_OPEN = {"(": ")", "[": "]", "{": "}"}
_CLOSE = {v: k for k, v in _OPEN.items()}


@dataclass(frozen=True)
class Token:
    """One token: ``kind`` (string, number, name, op), its text, 1-based line and column,
    and its character span in the program."""

    kind: str
    text: str
    line: int
    col: int
    start: int
    end: int


def tokenize(text: str) -> list[Token]:
    """The program's tokens without whitespace and comments.

    Raises
    ------
    InputError
        ``line:column: what`` for an unterminated string, a character that is not URScript,
        a bracket that does not close or closes the wrong one (e.g. a binary file).
    """
    out: list[Token] = []
    line, line_start, pos = 1, 0, 0
    stack: list[Token] = []
    n = len(text)
    while pos < n:
        m = _TOKEN.match(text, pos)
        if m is None:
            ch = text[pos]
            col = pos - line_start + 1
            if ch in "\"'":
                raise InputError(f"{line}:{col}: string literal is not closed on its line")
            raise InputError(f"{line}:{col}: character {ch!r} is not URScript")
        kind = m.lastgroup or ""
        if kind == "nl":
            line += 1
            line_start = m.end()
        elif kind not in ("ws", "comment"):
            tok = Token(kind, m.group(), line, pos - line_start + 1, pos, m.end())
            if kind == "op" and tok.text in _OPEN:
                stack.append(tok)
            elif kind == "op" and tok.text in _CLOSE:
                if not stack or stack[-1].text != _CLOSE[tok.text]:
                    raise InputError(f"{tok.line}:{tok.col}: {tok.text!r} closes nothing open")
                stack.pop()
            out.append(tok)
        pos = m.end()
    if stack:
        t = stack[-1]
        raise InputError(f"{t.line}:{t.col}: {t.text!r} is never closed")
    return out


@dataclass(frozen=True)
class JointTargets:
    """The move commands of a program.

    ``q`` shape (n, n_joints) rad, ``lines`` / ``commands`` / ``spans`` per readable target
    (``spans``: character span of the list's contents, for :func:`replace_targets`);
    ``unreadable``: ``(line, column, command, why)`` of every motion whose target is not a
    literal joint list of the robot's length, or that has no joint target.  ``left``: those
    of them the caller chose to leave as written (``compensate --leave``).
    """

    q: F
    lines: tuple[int, ...]
    commands: tuple[str, ...]
    spans: tuple[tuple[int, int], ...]
    unreadable: tuple[tuple[int, int, str, str], ...]
    left: tuple[tuple[int, int, str, str], ...] = ()


def _close_of(toks: list[Token], i: int) -> int:
    """Index of the token closing the bracket at ``toks[i]`` (brackets are balanced)."""
    depth = 0
    for j in range(i, len(toks)):
        t = toks[j]
        if t.kind == "op" and t.text in _OPEN:
            depth += 1
        elif t.kind == "op" and t.text in _CLOSE:
            depth -= 1
            if depth == 0:
                return j
    raise AssertionError("unbalanced brackets after tokenize")  # pragma: no cover


def _literal_list(toks: list[Token]) -> list[float] | None:
    """Numbers of ``[a, -b, +c]`` tokens (without the brackets), None if not all literals."""
    vals: list[float] = []
    i = 0
    while i < len(toks):
        sign = 1.0
        if toks[i].kind == "op" and toks[i].text in "+-" and len(toks[i].text) == 1:
            sign = -1.0 if toks[i].text == "-" else 1.0
            i += 1
        if i >= len(toks) or toks[i].kind != "number":
            return None
        v = sign * float(toks[i].text)
        if not math.isfinite(v):
            return None
        vals.append(v)
        i += 1
        if i < len(toks):
            if not (toks[i].kind == "op" and toks[i].text == ","):
                return None
            i += 1
            if i == len(toks):
                return None
    return vals


def _top_level_args(args: list[Token]) -> list[list[Token]]:
    """A call's argument tokens split at its top-level commas."""
    out: list[list[Token]] = [[]]
    depth = 0
    for a in args:
        if a.kind == "op" and a.text in _OPEN:
            depth += 1
        elif a.kind == "op" and a.text in _CLOSE:
            depth -= 1
        if depth == 0 and a.kind == "op" and a.text == ",":
            out.append([])
        else:
            out[-1].append(a)
    return out


def _target(
    text: str, arg: list[Token], n_joints: int
) -> tuple[list[float], tuple[int, int]] | str:
    """A literal joint list argument's values and the span of its contents, or why not."""
    if not arg:
        return "has no target"
    first = arg[0]
    if first.kind == "name" and first.text == "p" and len(arg) > 1 and arg[1].text == "[":
        return "to a Cartesian pose p[...] has no joint target; use joint lists"
    if first.text != "[":
        what = text[first.start : arg[-1].end]
        what = what if len(what) <= 40 else what[:37] + "..."
        return f"target {what!r} is not a literal joint list"
    lclose = _close_of(arg, 0)
    if lclose != len(arg) - 1:
        return "target is an expression, not a literal list"
    vals = _literal_list(arg[1:lclose])
    if vals is None:
        return "joint list holds something other than numbers"
    if len(vals) != n_joints:
        return f"has {len(vals)} joint values, the robot has {n_joints}"
    return vals, (arg[0].end, arg[lclose].start)


def joint_targets(text: str, n_joints: int) -> JointTargets:
    """Every motion command of a URScript program (see the module doc).

    Raises
    ------
    InputError
        The text does not tokenize (``line:column: what``).
    """
    toks = tokenize(text)
    q: list[list[float]] = []
    lines: list[int] = []
    cmds: list[str] = []
    spans: list[tuple[int, int]] = []
    bad: list[tuple[int, int, str, str]] = []
    for i, t in enumerate(toks):
        if t.kind != "name" or t.text not in MOTIONS:
            continue
        if i > 0 and toks[i - 1].kind == "name" and toks[i - 1].text == "def":
            continue  # a program defining its own function of that name
        if i > 0 and toks[i - 1].kind == "op" and toks[i - 1].text == ".":
            continue  # a member, not the built-in
        if i + 1 >= len(toks) or toks[i + 1].text != "(":
            bad.append((t.line, t.col, t.text, "not called with arguments"))
            continue
        if t.text in UNTARGETED_MOTIONS:
            bad.append(
                (t.line, t.col, t.text, "moves the arm without a joint target to compensate")
            )
            continue
        args = _top_level_args(toks[i + 2 : _close_of(toks, i + 1)])
        parts = [("", args[0])] if t.text != "movec" else [("via point ", args[0])]
        if t.text == "movec":
            parts.append(("end point ", args[1] if len(args) > 1 else []))
        found = [(name, _target(text, arg, n_joints)) for name, arg in parts]
        why = [f"{name}{r}" if name else r for name, r in found if isinstance(r, str)]
        if why:  # a movec is compensated whole or refused whole
            bad.append((t.line, t.col, t.text, "; ".join(why)))
            continue
        for _, r in found:
            assert not isinstance(r, str)
            q.append(r[0])
            lines.append(t.line)
            cmds.append(t.text)
            spans.append(r[1])
    return JointTargets(
        q=np.array(q, dtype=float).reshape(-1, n_joints),
        lines=tuple(lines),
        commands=tuple(cmds),
        spans=tuple(spans),
        unreadable=tuple(bad),
    )


def replace_targets(text: str, spans: tuple[tuple[int, int], ...] | list, q: ArrayLike) -> str:
    """The program with each joint list's contents at ``spans`` replaced by a row of ``q`` (rad)."""
    qa = np.atleast_2d(np.asarray(q, float))
    out, pos = [], 0
    for (a, b), row in zip(spans, qa, strict=True):
        out.append(text[pos:a])
        out.append(", ".join(f"{v:.9f}" for v in row))
        pos = b
    out.append(text[pos:])
    return "".join(out)
