"""URScript joint targets: one tokenizer, shared by ``predict`` and ``compensate``.

A pure reader of a program's *text* (no files): it knows comments (``#`` to the end of the
line), string literals (``"…"`` and ``'…'`` with backslash escapes), brackets nested to any
depth, and whitespace or comments between a function name and its ``(``.  A move command
(``movej``, ``movel``, ``movep``, ``servoj``) whose first argument is a literal joint list
``[q1, …, qN]`` (numbers in rad, an optional sign each) is a *readable* target.  Every
other first argument -- a variable, a pose literal ``p[…]``, an expression, a list of the
wrong length -- is an *unreadable* target, reported with its line and column and never
guessed.  Text inside comments and strings is never a target.

SYNOPSIS::

    t = joint_targets(text, n_joints=6)
    t.q, t.lines, t.spans          # readable targets (rad), their lines, their list contents
    t.unreadable                   # (line, column, command, why) of every other move
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

MOVES = ("movej", "movel", "movep", "servoj")

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
    ``unreadable``: ``(line, column, command, why)`` of every move whose target is not a
    literal joint list of the robot's length.
    """

    q: F
    lines: tuple[int, ...]
    commands: tuple[str, ...]
    spans: tuple[tuple[int, int], ...]
    unreadable: tuple[tuple[int, int, str, str], ...]


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


def joint_targets(text: str, n_joints: int) -> JointTargets:
    """Every ``movej/movel/movep/servoj`` call of a URScript program (see the module doc).

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
        if t.kind != "name" or t.text not in MOVES:
            continue
        if i > 0 and toks[i - 1].kind == "name" and toks[i - 1].text == "def":
            continue  # a program defining its own function of that name
        if i > 0 and toks[i - 1].kind == "op" and toks[i - 1].text == ".":
            continue  # a member, not the built-in
        if i + 1 >= len(toks) or toks[i + 1].text != "(":
            bad.append((t.line, t.col, t.text, "not called with arguments"))
            continue
        close = _close_of(toks, i + 1)
        args = toks[i + 2 : close]
        if not args:
            bad.append((t.line, t.col, t.text, "has no target"))
            continue
        first = args[0]
        if first.kind == "name" and first.text == "p" and len(args) > 1 and args[1].text == "[":
            bad.append(
                (
                    t.line,
                    t.col,
                    t.text,
                    "to a Cartesian pose p[...] has no joint target; use joint lists",
                )
            )
            continue
        if first.text != "[":
            end = next(
                (k for k, a in enumerate(args) if a.kind == "op" and a.text == ","), len(args)
            )
            what = text[first.start : args[end - 1].end]
            what = what if len(what) <= 40 else what[:37] + "..."
            bad.append((t.line, t.col, t.text, f"target {what!r} is not a literal joint list"))
            continue
        lclose = _close_of(args, 0)
        inner = args[1:lclose]
        after = args[lclose + 1] if lclose + 1 < len(args) else None
        if after is not None and after.text != ",":
            bad.append((t.line, t.col, t.text, "target is an expression, not a literal list"))
            continue
        vals = _literal_list(inner)
        if vals is None:
            bad.append((t.line, t.col, t.text, "joint list holds something other than numbers"))
            continue
        if len(vals) != n_joints:
            bad.append(
                (t.line, t.col, t.text, f"has {len(vals)} joint values, the robot has {n_joints}")
            )
            continue
        q.append(vals)
        lines.append(t.line)
        cmds.append(t.text)
        spans.append((args[0].end, args[lclose].start))
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
