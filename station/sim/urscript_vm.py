"""A URScript interpreter for the simulated controller: the subset cell programs use.

Programs arrive on the primary, secondary and realtime interfaces (30001, 30002, 30003) as
text.  They are read with the project's URScript tokenizer
(:func:`quickhealth.identify.urscript.tokenize`), parsed into statements and run by a tree
walker in the program's own thread.  The language subset:

- ``def``/``sec`` … ``end`` (the program, and local functions with parameters and
  ``return``), ``if``/``elif``/``else``, ``while``, ``break``, ``continue``, ``halt``;
- assignments (``x = …``, ``global x = …``, ``local x = …``, ``x[i] = …``), numbers,
  ``True``/``False``, strings, lists ``[…]``, pose literals ``p[…]``, indexing, the
  arithmetic ``+ - * / %``, comparisons, ``and``/``or``/``not``;
- the built-ins of :data:`BUILTINS` (moves, ``sleep``, ``sync``, ``textmsg``, ``popup``,
  registers, digital outputs, kinematics, a little maths).

Anything else is an error reported as a UR controller reports it: a name that is neither
defined nor built in is ``Compile error: name 'x' is not defined`` before anything runs; a
statement the subset does not have is a compile error with its line; a wrong value at run
time (a list index out of range, a division by zero, an unreachable pose) is a runtime
error that stops the program.  Both go to the primary and secondary clients as a
``RUNTIME_EXCEPTION`` robot message with line and column (:mod:`.primary`).

The interpreter knows nothing of the controller's internals: it calls a :class:`Host`
(the controller), which moves the arm, waits and reads the registers.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Protocol, TypeAlias

from ...identify.errors import InputError
from ...identify.urscript import Token, tokenize


class ScriptError(Exception):
    """A compile or runtime error at ``line``:``col`` (1-based; 0 when unknown)."""

    def __init__(self, kind: str, message: str, line: int = 0, col: int = 0) -> None:
        super().__init__(message)
        self.kind = kind  # "compile" or "runtime"
        self.message = message
        self.line = line
        self.col = col

    def describe(self) -> str:
        """The controller's wording: ``Compile error: …`` / ``Runtime error: …``."""
        where = f" (line {self.line})" if self.line else ""
        return f"{self.kind.capitalize()} error: {self.message}{where}"


class Halt(Exception):
    """``halt``: the program stops (not an error)."""


class Stopped(Exception):
    """The program was stopped from outside (dashboard, a new program, a restart)."""


class Pose(list):  # type: ignore[type-arg]
    """A URScript pose ``p[x, y, z, rx, ry, rz]`` (m, rotation vector in rad)."""

    def __repr__(self) -> str:
        return "p[" + ", ".join(f"{v:.6g}" for v in self) + "]"


#: A URScript value: a number, a boolean, a string, a pose or a list of values.
Value: TypeAlias = "bool | int | float | str | Pose | list[Value]"
#: What a syntax node holds in its slots: nodes, names, literal values, lists of them.
Slot: TypeAlias = "Node | Function | Value | list[Slot] | tuple[Slot, ...] | dict[str, Slot] | None"


class Host(Protocol):
    """What a program may ask of the controller."""

    def move(self, kind: str, target: Value, a: float, v: float, t: float, r: float) -> None: ...
    def sleep(self, seconds: float) -> None: ...
    def sync(self) -> None: ...
    def steptime(self) -> float: ...
    def textmsg(self, text: str) -> None: ...
    def popup(self, text: str, title: str, warning: bool, error: bool, blocking: bool) -> None: ...
    def actual_q(self) -> list[float]: ...
    def actual_tcp_pose(self) -> list[float]: ...
    def target_tcp_pose(self) -> list[float]: ...
    def inverse_kin(self, pose: list[float], qnear: list[float] | None) -> list[float] | None: ...
    def forward_kin(self, q: list[float] | None, tcp: list[float] | None) -> list[float]: ...
    def set_tcp(self, pose: list[float]) -> None: ...
    def set_payload(self, mass: float, cog: list[float] | None) -> None: ...
    def register(self, kind: str, index: int, value: Value | None = None) -> Value | None: ...
    def digital_out(self, index: int, value: bool) -> None: ...
    def check(self) -> None: ...


# ------------------------------------------------------------------------------- syntax


@dataclass
class Node:
    kind: str
    line: int
    col: int
    a: Slot = None
    b: Slot = None
    c: Slot = None


@dataclass
class Function:
    name: str
    params: list[str]
    defaults: list[Node | None]
    body: list[Node]
    line: int


@dataclass
class Program:
    """A compiled program: its top-level statements and functions."""

    name: str
    body: list[Node]
    functions: dict[str, Function] = field(default_factory=dict)
    secondary: bool = False


_CMP = ("==", "!=", "<", "<=", ">", ">=")
_BLOCK_END = ("end", "elif", "else")
_UNSUPPORTED = {
    "thread": "threads are not in the simulator's URScript subset",
    "run": "threads are not in the simulator's URScript subset",
    "kill": "threads are not in the simulator's URScript subset",
    "join": "threads are not in the simulator's URScript subset",
    "enter_critical": "critical sections are not in the simulator's URScript subset",
    "exit_critical": "critical sections are not in the simulator's URScript subset",
    "for": "'for' is not URScript",
    "struct": "structs are not in the simulator's URScript subset",
}


def _statements(toks: list[Token]) -> list[list[Token]]:
    """Tokens grouped into statements: a new line at bracket depth 0 starts one, and a
    block header ends at its ``:``."""
    out: list[list[Token]] = []
    cur: list[Token] = []
    depth = 0
    line = -1
    for t in toks:
        if depth == 0 and cur and t.line != line:
            out.append(cur)
            cur = []
        cur.append(t)
        line = t.line
        if t.kind == "op" and t.text in "([{":
            depth += 1
        elif t.kind == "op" and t.text in ")]}":
            depth -= 1
        elif t.kind == "op" and t.text == ":" and depth == 0:
            out.append(cur)
            cur = []
    if cur:
        out.append(cur)
    return out


class _Parser:
    def __init__(self, text: str) -> None:
        try:
            toks = tokenize(text)
        except InputError as exc:
            msg = str(exc)
            line, col = 0, 0
            parts = msg.split(":", 2)
            if len(parts) == 3 and parts[0].isdigit() and parts[1].isdigit():
                line, col, msg = int(parts[0]), int(parts[1]), parts[2].strip()
            raise ScriptError("compile", f"syntax error: {msg}", line, col) from None
        self.stmts = _statements(toks)
        self.i = 0

    # -- statements -----------------------------------------------------------------
    def block(self, ends: tuple[str, ...]) -> tuple[list[Node], list[Token] | None]:
        body: list[Node] = []
        while self.i < len(self.stmts):
            st = self.stmts[self.i]
            head = st[0]
            if head.kind == "name" and head.text in ends:
                return body, st
            self.i += 1
            body.append(self.statement(st))
        return body, None

    def _err(self, t: Token, msg: str) -> ScriptError:
        return ScriptError("compile", msg, t.line, t.col)

    def _expect_colon(self, st: list[Token]) -> list[Token]:
        if not (st[-1].kind == "op" and st[-1].text == ":"):
            raise self._err(st[-1], f"syntax error: ':' expected after {st[0].text!r}")
        return st[1:-1]

    def _until_end(self, st: list[Token]) -> list[Node]:
        body, end = self.block(("end",))
        if end is None:
            raise self._err(st[0], f"'{st[0].text}' on line {st[0].line} has no 'end'")
        if len(end) != 1:
            raise self._err(end[1], "syntax error: nothing may follow 'end'")
        self.i += 1
        return body

    def function(self, st: list[Token]) -> Function:
        inner = self._expect_colon(st)
        if (
            len(inner) < 3
            or inner[0].kind != "name"
            or inner[1].text != "("
            or inner[-1].text != ")"
        ):
            raise self._err(st[0], f"syntax error in '{st[0].text}' header")
        name = inner[0].text
        params: list[str] = []
        defaults: list[Node | None] = []
        args = inner[2:-1]
        for chunk in _split(args, ","):
            if not chunk:
                continue
            if chunk[0].kind != "name":
                raise self._err(chunk[0], "syntax error: parameter name expected")
            params.append(chunk[0].text)
            if len(chunk) > 1:
                if chunk[1].text != "=":
                    raise self._err(chunk[1], "syntax error in parameter list")
                defaults.append(_Expr(chunk[2:], self).parse_all())
            else:
                defaults.append(None)
        body = self._until_end(st)
        return Function(name, params, defaults, body, st[0].line)

    def statement(self, st: list[Token]) -> Node:
        h = st[0]
        word = h.text if h.kind == "name" else ""
        if word in ("def", "sec"):
            f = self.function(st)
            return Node("def", h.line, h.col, f)
        if word in _UNSUPPORTED:
            raise self._err(h, _UNSUPPORTED[word])
        if word == "if":
            branches: list[tuple[Node | None, list[Node]]] = []
            cond = _Expr(self._expect_colon(st), self).parse_all()
            while True:
                body, end = self.block(_BLOCK_END)
                branches.append((cond, body))
                if end is None:
                    raise self._err(h, f"'if' on line {h.line} has no 'end'")
                self.i += 1
                if end[0].text == "end":
                    break
                if end[0].text == "elif":
                    cond = _Expr(self._expect_colon(end), self).parse_all()
                else:
                    if len(self._expect_colon(end)) != 0:
                        raise self._err(end[0], "syntax error after 'else'")
                    body, end2 = self.block(("end",))
                    if end2 is None:
                        raise self._err(h, f"'if' on line {h.line} has no 'end'")
                    self.i += 1
                    branches.append((None, body))
                    break
            return Node("if", h.line, h.col, branches)
        if word == "while":
            cond = _Expr(self._expect_colon(st), self).parse_all()
            return Node("while", h.line, h.col, cond, self._until_end(st))
        if word in ("break", "continue", "halt") and len(st) == 1:
            return Node(word, h.line, h.col)
        if word == "return":
            val = _Expr(st[1:], self).parse_all() if len(st) > 1 else None
            return Node("return", h.line, h.col, val)
        if word in _BLOCK_END:
            raise self._err(h, f"syntax error: '{word}' without an open block")
        scope = None
        rest = st
        if word in ("global", "local"):
            scope, rest = word, st[1:]
        eq = next(
            (
                k
                for k, t in enumerate(rest)
                if t.kind == "op" and t.text == "=" and _depth(rest, k) == 0
            ),
            None,
        )
        if eq is not None:
            target = _Expr(rest[:eq], self).parse_all()
            if target.kind not in ("name", "index") or (scope and target.kind != "name"):
                raise self._err(rest[0], "syntax error: cannot assign to this")
            value = _Expr(rest[eq + 1 :], self).parse_all()
            return Node("assign", h.line, h.col, target, value, scope)
        if scope is not None:
            raise self._err(h, f"syntax error: '{scope}' needs an assignment")
        return Node("expr", h.line, h.col, _Expr(st, self).parse_all())


def _depth(toks: list[Token], k: int) -> int:
    d = 0
    for t in toks[:k]:
        if t.kind == "op" and t.text in "([{":
            d += 1
        elif t.kind == "op" and t.text in ")]}":
            d -= 1
    return d


def _split(toks: list[Token], sep: str) -> list[list[Token]]:
    out: list[list[Token]] = [[]]
    d = 0
    for t in toks:
        if t.kind == "op" and t.text in "([{":
            d += 1
        elif t.kind == "op" and t.text in ")]}":
            d -= 1
        if d == 0 and t.kind == "op" and t.text == sep:
            out.append([])
        else:
            out[-1].append(t)
    return out


class _Expr:
    """Precedence climbing over one statement's tokens."""

    def __init__(self, toks: list[Token], parser: _Parser) -> None:
        self.t = toks
        self.k = 0
        self.p = parser

    def parse_all(self) -> Node:
        if not self.t:
            raise ScriptError("compile", "syntax error: expression expected")
        n = self.or_()
        if self.k < len(self.t):
            t = self.t[self.k]
            raise ScriptError("compile", f"syntax error near {t.text!r}", t.line, t.col)
        return n

    def peek(self) -> Token | None:
        return self.t[self.k] if self.k < len(self.t) else None

    def take(self, text: str | None = None) -> Token:
        t = self.peek()
        if t is None:
            last = self.t[-1]
            raise ScriptError(
                "compile", "syntax error: unexpected end of line", last.line, last.col
            )
        if text is not None and t.text != text:
            raise ScriptError("compile", f"syntax error: {text!r} expected", t.line, t.col)
        self.k += 1
        return t

    def _is(self, *texts: str) -> bool:
        t = self.peek()
        return t is not None and t.text in texts and t.kind in ("op", "name")

    def or_(self) -> Node:
        n = self.and_()
        while self._is("or", "xor"):
            t = self.take()
            n = Node("bool", t.line, t.col, t.text, n, self.and_())
        return n

    def and_(self) -> Node:
        n = self.not_()
        while self._is("and"):
            t = self.take()
            n = Node("bool", t.line, t.col, "and", n, self.not_())
        return n

    def not_(self) -> Node:
        if self._is("not"):
            t = self.take()
            return Node("not", t.line, t.col, self.not_())
        return self.cmp()

    def cmp(self) -> Node:
        n = self.add()
        if self._is(*_CMP):
            t = self.take()
            n = Node("bin", t.line, t.col, t.text, n, self.add())
        return n

    def add(self) -> Node:
        n = self.mul()
        while self._is("+", "-"):
            t = self.take()
            n = Node("bin", t.line, t.col, t.text, n, self.mul())
        return n

    def mul(self) -> Node:
        n = self.unary()
        while self._is("*", "/", "%"):
            t = self.take()
            n = Node("bin", t.line, t.col, t.text, n, self.unary())
        return n

    def unary(self) -> Node:
        if self._is("-", "+"):
            t = self.take()
            return Node("neg" if t.text == "-" else "pos", t.line, t.col, self.unary())
        return self.postfix()

    def postfix(self) -> Node:
        n = self.atom()
        while True:
            if self._is("("):
                t = self.take("(")
                args, kwargs = self.call_args()
                if n.kind != "name":
                    raise ScriptError(
                        "compile", "syntax error: only names can be called", t.line, t.col
                    )
                n = Node("call", n.line, n.col, n.a, args, kwargs)
            elif self._is("["):
                t = self.take("[")
                idx = self.or_()
                self.take("]")
                n = Node("index", t.line, t.col, n, idx)
            else:
                return n

    def call_args(self) -> tuple[list[Node], dict[str, Node]]:
        args: list[Node] = []
        kwargs: dict[str, Node] = {}
        if self._is(")"):
            self.take(")")
            return args, kwargs
        while True:
            t = self.peek()
            nxt = self.t[self.k + 1] if self.k + 1 < len(self.t) else None
            if t is not None and t.kind == "name" and nxt is not None and nxt.text == "=":
                self.k += 2
                kwargs[t.text] = self.or_()
            else:
                if kwargs:
                    raise ScriptError(
                        "compile",
                        "syntax error: positional argument after a named one",
                        t.line if t else 0,
                        t.col if t else 0,
                    )
                args.append(self.or_())
            if self._is(","):
                self.take(",")
                continue
            self.take(")")
            return args, kwargs

    def seq(self, close: str) -> list[Node]:
        items: list[Node] = []
        if self._is(close):
            self.take(close)
            return items
        while True:
            items.append(self.or_())
            if self._is(","):
                self.take(",")
                continue
            self.take(close)
            return items

    def atom(self) -> Node:
        t = self.take()
        if t.kind == "number":
            text = t.text
            v: Value = float(text) if any(c in text for c in ".eE") else int(text)
            return Node("const", t.line, t.col, v)
        if t.kind == "string":
            return Node("const", t.line, t.col, _unquote(t.text))
        if t.kind == "name":
            if t.text in ("True", "False"):
                return Node("const", t.line, t.col, t.text == "True")
            nxt = self.peek()
            if t.text == "p" and nxt is not None and nxt.text == "[" and nxt.start == t.end:
                self.take("[")
                return Node("pose", t.line, t.col, self.seq("]"))
            if t.text in _UNSUPPORTED:
                raise ScriptError("compile", _UNSUPPORTED[t.text], t.line, t.col)
            return Node("name", t.line, t.col, t.text)
        if t.text == "[":
            return Node("list", t.line, t.col, self.seq("]"))
        if t.text == "(":
            n = self.or_()
            self.take(")")
            return n
        raise ScriptError("compile", f"syntax error near {t.text!r}", t.line, t.col)


def _unquote(s: str) -> str:
    body = s[1:-1]
    out = []
    i = 0
    while i < len(body):
        ch = body[i]
        if ch == "\\" and i + 1 < len(body):
            nxt = body[i + 1]
            out.append({"n": "\n", "t": "\t", "\\": "\\", '"': '"', "'": "'"}.get(nxt, nxt))
            i += 2
        else:
            out.append(ch)
            i += 1
    return "".join(out)


def compile_program(text: str) -> Program:
    """Parse a program; every name it calls must be a built-in or one of its functions.

    A text that is one top-level ``def``/``sec`` is that program; otherwise its top-level
    statements are the program (as the controller runs a bare script).

    Raises
    ------
    ScriptError
        A compile error (``kind == "compile"``) with its line and column.
    """
    p = _Parser(text)
    body, stray = p.block(())
    if stray is not None:  # pragma: no cover - block(()) stops only at the end
        raise ScriptError("compile", "syntax error", stray[0].line, stray[0].col)
    top = [n for n in body if n.kind == "def"]
    if len(body) == 1 and top:
        f: Function = top[0].a
        prog = Program(f.name, f.body, secondary=text.lstrip().startswith("sec"))
    else:
        prog = Program("<unnamed>", body)
    _collect_functions(prog.body, prog.functions)
    for fn in list(prog.functions.values()):
        _collect_functions(fn.body, prog.functions)
    _check_names(prog)
    return prog


def _collect_functions(body: list[Node], into: dict[str, Function]) -> None:
    for n in body:
        if n.kind == "def":
            into[n.a.name] = n.a


def _walk(node: Slot) -> Iterator[Node]:
    if isinstance(node, Node):
        yield node
        for part in (node.a, node.b, node.c):
            yield from _walk(part)
    elif isinstance(node, Function):
        for d in node.defaults:
            yield from _walk(d)
        for n in node.body:
            yield from _walk(n)
    elif isinstance(node, list | tuple):
        for x in node:
            yield from _walk(x)
    elif isinstance(node, dict):
        for x in node.values():
            yield from _walk(x)


def _check_names(prog: Program) -> None:
    for n in _walk(prog.body):
        if n.kind == "call" and n.a not in BUILTINS and n.a not in prog.functions:
            raise ScriptError("compile", f"name '{n.a}' is not defined", n.line, n.col)


# ------------------------------------------------------------------------------- running


class _Return(Exception):
    def __init__(self, value: Value) -> None:
        self.value = value


class _Break(Exception):
    pass


class _Continue(Exception):
    pass


class Interpreter:
    """Runs one compiled program against a :class:`Host` (call :meth:`run` in its thread)."""

    MAX_DEPTH = 100

    def __init__(self, program: Program, host: Host) -> None:
        self.prog = program
        self.host = host
        self.globals: dict[str, Value] = {}
        self.depth = 0
        self.line = 0

    def run(self) -> None:
        """Run to the end.  Raises :class:`ScriptError` (runtime), :class:`Halt` or
        :class:`Stopped`."""
        self.exec_block(self.prog.body, self.globals, None)

    def _rt(self, node: Node, msg: str) -> ScriptError:
        return ScriptError("runtime", msg, node.line, node.col)

    def exec_block(
        self, body: list[Node], env: dict[str, Value], local: dict[str, Value] | None
    ) -> None:
        for st in body:
            self.host.check()
            self.line = st.line
            self.exec(st, env, local)

    def exec(self, st: Node, env: dict[str, Value], local: dict[str, Value] | None) -> None:
        k = st.kind
        if k == "expr":
            self.eval(st.a, env, local)
        elif k == "assign":
            self.assign(st, env, local)
        elif k == "if":
            for cond, body in st.a:
                if cond is None or self.truth(cond, env, local):
                    self.exec_block(body, env, local)
                    break
        elif k == "while":
            while self.truth(st.a, env, local):
                try:
                    self.exec_block(st.b, env, local)
                except _Break:
                    break
                except _Continue:
                    continue
                self.host.check()
        elif k == "def":
            pass  # collected at compile time
        elif k == "return":
            raise _Return(None if st.a is None else self.eval(st.a, env, local))
        elif k == "break":
            raise _Break()
        elif k == "continue":
            raise _Continue()
        elif k == "halt":
            raise Halt()
        else:  # pragma: no cover - the parser makes no other kinds
            raise self._rt(st, f"cannot run a {k!r} statement")

    def truth(self, node: Node, env: dict[str, Value], local: dict[str, Value] | None) -> bool:
        v = self.eval(node, env, local)
        if not isinstance(v, bool | int | float):
            raise self._rt(node, f"a condition must be a boolean, not {_type(v)}")
        return bool(v)

    def assign(self, st: Node, env: dict[str, Value], local: dict[str, Value] | None) -> None:
        target, value, scope = st.a, self.eval(st.b, env, local), st.c
        if isinstance(value, list):
            value = type(value)(value)  # lists are values in URScript
        if target.kind == "name":
            name = target.a
            if (
                local is None
                or scope == "global"
                or (scope is None and name not in local and name in env)
            ):
                env[name] = value
            else:
                local[name] = value
            return
        container = self.eval(target.a, env, local)
        idx = self.eval(target.b, env, local)
        if not isinstance(container, list):
            raise self._rt(target, f"cannot index {_type(container)}")
        i = self._index(target, container, idx)
        container[i] = value

    def _index(self, node: Node, container: list[Value], idx: Value) -> int:
        if isinstance(idx, bool) or not isinstance(idx, int | float) or idx != int(idx):
            raise self._rt(node, f"list index must be an integer, not {_type(idx)}")
        i = int(idx)
        if not 0 <= i < len(container):
            raise self._rt(node, f"index {i} out of range (length {len(container)})")
        return i

    def lookup(self, node: Node, env: dict[str, Value], local: dict[str, Value] | None) -> Value:
        name = node.a
        if local is not None and name in local:
            return local[name]
        if name in env:
            return env[name]
        raise self._rt(node, f"variable '{name}' is not defined")

    def eval(self, n: Node, env: dict[str, Value], local: dict[str, Value] | None) -> Value:
        k = n.kind
        if k == "const":
            return n.a
        if k == "name":
            return self.lookup(n, env, local)
        if k == "list":
            return [self.eval(x, env, local) for x in n.a]
        if k == "pose":
            vals = [self._num(x, self.eval(x, env, local)) for x in n.a]
            if len(vals) != 6:
                raise self._rt(n, f"a pose has 6 elements, not {len(vals)}")
            return Pose(float(v) for v in vals)
        if k == "index":
            c = self.eval(n.a, env, local)
            if not isinstance(c, list):
                raise self._rt(n, f"cannot index {_type(c)}")
            return c[self._index(n, c, self.eval(n.b, env, local))]
        if k == "neg":
            return -self._num(n, self.eval(n.a, env, local))
        if k == "pos":
            return self._num(n, self.eval(n.a, env, local))
        if k == "not":
            return not self.truth(n.a, env, local)
        if k == "bool":
            left = self.truth(n.b, env, local)
            if n.a == "and":
                return left and self.truth(n.c, env, local)
            if n.a == "or":
                return left or self.truth(n.c, env, local)
            return left != self.truth(n.c, env, local)
        if k == "bin":
            return self.binary(n, self.eval(n.b, env, local), self.eval(n.c, env, local))
        if k == "call":
            return self.call(n, env, local)
        raise self._rt(n, f"cannot evaluate {k!r}")  # pragma: no cover

    def _num(self, n: Node, v: Value) -> float | int:
        if isinstance(v, bool) or not isinstance(v, int | float):
            raise self._rt(n, f"a number is needed, not {_type(v)}")
        return v

    def binary(self, n: Node, x: Value, y: Value) -> Value:
        op = n.a
        if op in ("==", "!="):
            eq = x == y
            return eq if op == "==" else not eq
        x, y = self._num(n, x), self._num(n, y)
        if op == "+":
            return x + y
        if op == "-":
            return x - y
        if op == "*":
            return x * y
        if op in ("/", "%"):
            if y == 0:
                raise self._rt(n, "division by zero")
            if op == "%":
                return math.fmod(x, y) if isinstance(x, float) or isinstance(y, float) else x % y
            return (
                x / y
                if (isinstance(x, float) or isinstance(y, float))
                else (x // y if x % y == 0 else x / y)
            )
        return {"<": x < y, "<=": x <= y, ">": x > y, ">=": x >= y}[op]

    def call(self, n: Node, env: dict[str, Value], local: dict[str, Value] | None) -> Value:
        args = [self.eval(a, env, local) for a in n.b]
        kwargs = {k: self.eval(v, env, local) for k, v in n.c.items()}
        fn = self.prog.functions.get(n.a)
        if fn is not None:
            return self.call_function(n, fn, args, kwargs, env)
        spec = BUILTINS[n.a]
        try:
            bound = spec.bind(args, kwargs)
        except TypeError as exc:
            raise self._rt(n, f"{n.a}(): {exc}") from None
        try:
            return spec.fn(self, n, **bound)
        except ScriptError:
            raise
        except (Halt, Stopped):
            raise
        except (TypeError, ValueError, IndexError) as exc:
            raise self._rt(n, f"{n.a}(): {exc}") from None

    def call_function(
        self,
        n: Node,
        fn: Function,
        args: list[Value],
        kwargs: dict[str, Value],
        env: dict[str, Value],
    ) -> Value:
        if len(args) > len(fn.params):
            raise self._rt(n, f"{fn.name}() takes {len(fn.params)} arguments, {len(args)} given")
        local: dict[str, Value] = {}
        for i, p in enumerate(fn.params):
            if i < len(args):
                local[p] = args[i]
            elif p in kwargs:
                local[p] = kwargs.pop(p)
            elif fn.defaults[i] is not None:
                local[p] = self.eval(fn.defaults[i], env, None)  # type: ignore[arg-type]
            else:
                raise self._rt(n, f"{fn.name}(): argument '{p}' missing")
        if kwargs:
            raise self._rt(n, f"{fn.name}(): unknown argument '{next(iter(kwargs))}'")
        self.depth += 1
        if self.depth > self.MAX_DEPTH:
            raise self._rt(n, "call stack too deep")
        try:
            self.exec_block(fn.body, env, local)
        except _Return as r:
            return r.value
        finally:
            self.depth -= 1
        return None


def _type(v: Value) -> str:
    if isinstance(v, Pose):
        return "a pose"
    if isinstance(v, bool):
        return "a boolean"
    if isinstance(v, int | float):
        return "a number"
    if isinstance(v, str):
        return "a string"
    if isinstance(v, list):
        return "a list"
    return "nothing" if v is None else type(v).__name__


# ------------------------------------------------------------------------------- built-ins


@dataclass(frozen=True)
class Builtin:
    """A built-in function: parameter names, their defaults (``REQUIRED`` if none), body."""

    params: tuple[str, ...]
    defaults: tuple[Value, ...]
    fn: Callable[..., Value | None]

    def bind(self, args: list[Value], kwargs: dict[str, Value]) -> dict[str, Value]:
        if len(args) > len(self.params):
            raise TypeError(f"takes at most {len(self.params)} arguments, {len(args)} given")
        out: dict[str, Value] = dict(zip(self.params, args, strict=False))
        for k, v in kwargs.items():
            if k not in self.params:
                raise TypeError(f"unknown argument '{k}'")
            if k in out:
                raise TypeError(f"argument '{k}' given twice")
            out[k] = v
        for p, d in zip(self.params, self.defaults, strict=True):
            if p not in out:
                if d is REQUIRED:
                    raise TypeError(f"argument '{p}' missing")
                out[p] = d
        return out


REQUIRED = object()


def _nums(vm: Interpreter, n: Node, v: Value, k: int, what: str) -> list[float]:
    if not isinstance(v, list) or len(v) != k:
        raise vm._rt(n, f"{what} must be a list of {k} numbers, not {_type(v)}")
    return [float(vm._num(n, x)) for x in v]


def _pos(vm: Interpreter, n: Node, v: Value, what: str) -> float:
    x = float(vm._num(n, v))
    if not math.isfinite(x) or x < 0:
        raise vm._rt(n, f"{what} must be a finite number >= 0, got {x}")
    return x


def _move(kind: str) -> Callable[..., None]:
    def run(
        vm: Interpreter,
        n: Node,
        *,
        target: Value,
        a: Value,
        v: Value,
        t: Value = 0.0,
        r: Value = 0.0,
    ) -> None:
        if not isinstance(target, list) or len(target) != 6:
            raise vm._rt(n, f"{n.a}(): the target must be a pose p[...] or 6 joint angles")
        vals = [float(vm._num(n, x)) for x in target]
        if not all(math.isfinite(x) for x in vals):
            raise vm._rt(n, f"{n.a}(): the target is not finite")
        tgt: Value = Pose(vals) if isinstance(target, Pose) else vals
        vm.host.move(
            kind,
            tgt,
            _pos(vm, n, a, "a"),
            _pos(vm, n, v, "v"),
            _pos(vm, n, t, "t"),
            _pos(vm, n, r, "r"),
        )

    return run


def _textmsg(vm: Interpreter, n: Node, *, s1: Value, s2: Value = "") -> None:
    vm.host.textmsg(_str(s1) + _str(s2))


def _str(v: Value) -> str:
    if isinstance(v, str):
        return v
    if isinstance(v, bool):
        return "True" if v else "False"
    if isinstance(v, Pose):
        return "p[" + ", ".join(_str(x) for x in v) + "]"
    if isinstance(v, list):
        return "[" + ", ".join(_str(x) for x in v) + "]"
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


def _popup(
    vm: Interpreter,
    n: Node,
    *,
    s: Value,
    title: Value,
    warning: Value,
    error: Value,
    blocking: Value,
) -> None:
    vm.host.popup(_str(s), _str(title), bool(warning), bool(error), bool(blocking))


def _sleep(vm: Interpreter, n: Node, *, t: Value) -> None:
    vm.host.sleep(_pos(vm, n, t, "sleep time"))


def _reg(kind: str, write: bool) -> Callable[..., Value | None]:
    def run(
        vm: Interpreter, n: Node, *, address: Value, value: Value | None = None
    ) -> Value | None:
        i = vm._num(n, address)
        if i != int(i) or not 0 <= int(i) <= (127 if kind == "bit" else 47):
            raise vm._rt(n, f"{n.a}(): register {i} does not exist")
        if write:
            if kind == "int":
                val: Value = vm._num(n, value)
                if val != int(val) or not -(2**31) <= int(val) < 2**31:
                    raise vm._rt(n, f"{n.a}(): {val} is not a 32-bit integer")
                val = int(val)
            elif kind == "float":
                val = float(vm._num(n, value))
            else:
                val = bool(value)
            vm.host.register(f"output_{kind}", int(i), val)
            return None
        return vm.host.register(f"input_{kind}", int(i))

    return run


def _norm(vm: Interpreter, n: Node, *, a: Value) -> float:
    if isinstance(a, list):
        return math.sqrt(sum(float(vm._num(n, x)) ** 2 for x in a))
    return abs(float(vm._num(n, a)))


def _math1(f: Callable[[float], float]) -> Callable[..., float]:
    def run(vm: Interpreter, n: Node, *, f_: Value) -> float:
        try:
            return f(float(vm._num(n, f_)))
        except (ValueError, OverflowError) as exc:
            raise vm._rt(n, f"{n.a}(): {exc}") from None

    return run


def _get_inverse_kin(
    vm: Interpreter,
    n: Node,
    *,
    x: Value,
    qnear: Value,
    maxPositionError: Value,
    maxOrientationError: Value,
    tcp: Value,
) -> list[float]:
    pose = _nums(vm, n, x, 6, "x")
    near = None if qnear is None else _nums(vm, n, qnear, 6, "qnear")
    q = vm.host.inverse_kin(pose, near)
    if q is None:
        raise vm._rt(n, "get_inverse_kin(): no solution: the pose is out of reach")
    return q


def _get_forward_kin(vm: Interpreter, n: Node, *, q: Value, tcp: Value) -> Pose:
    qq = None if q is None else _nums(vm, n, q, 6, "q")
    tt = None if tcp is None else _nums(vm, n, tcp, 6, "tcp")
    return Pose(vm.host.forward_kin(qq, tt))


def _set_tcp(vm: Interpreter, n: Node, *, pose: Value) -> None:
    vm.host.set_tcp(_nums(vm, n, pose, 6, "pose"))


def _set_payload(vm: Interpreter, n: Node, *, m: Value, cog: Value) -> None:
    vm.host.set_payload(
        _pos(vm, n, m, "mass"), None if cog is None else _nums(vm, n, cog, 3, "cog")
    )


def _digital_out(vm: Interpreter, n: Node, *, n_: Value, b: Value) -> None:
    i = vm._num(n, n_)
    if i != int(i) or not 0 <= int(i) <= 7:
        raise vm._rt(n, f"{n.a}(): output {i} does not exist (0..7)")
    vm.host.digital_out(int(i), bool(b))


def _b(params: str, defaults: tuple[Value, ...], fn: Callable[..., Value | None]) -> Builtin:
    names = tuple(p for p in params.split(",") if p)
    return Builtin(names, defaults, fn)


_R = REQUIRED
BUILTINS: dict[str, Builtin] = {
    "movej": _b("target,a,v,t,r", (_R, 1.4, 1.05, 0.0, 0.0), _move("movej")),
    "movel": _b("target,a,v,t,r", (_R, 1.2, 0.25, 0.0, 0.0), _move("movel")),
    "movep": _b("target,a,v,r", (_R, 1.2, 0.25, 0.0), _move("movep")),
    "sleep": _b("t", (_R,), _sleep),
    "sync": _b("", (), lambda vm, n: vm.host.sync()),
    "get_steptime": _b("", (), lambda vm, n: vm.host.steptime()),
    "textmsg": _b("s1,s2", (_R, ""), _textmsg),
    "popup": _b("s,title,warning,error,blocking", (_R, "Popup", False, False, False), _popup),
    "set_standard_digital_out": _b("n_,b", (_R, _R), _digital_out),
    "set_digital_out": _b("n_,b", (_R, _R), _digital_out),
    "get_actual_joint_positions": _b("", (), lambda vm, n: list(vm.host.actual_q())),
    "get_actual_tcp_pose": _b("", (), lambda vm, n: Pose(vm.host.actual_tcp_pose())),
    "get_target_tcp_pose": _b("", (), lambda vm, n: Pose(vm.host.target_tcp_pose())),
    "get_inverse_kin": _b(
        "x,qnear,maxPositionError,maxOrientationError,tcp",
        (_R, None, 1e-10, 1e-10, None),
        _get_inverse_kin,
    ),
    "get_forward_kin": _b("q,tcp", (None, None), _get_forward_kin),
    "set_tcp": _b("pose", (_R,), _set_tcp),
    "set_payload": _b("m,cog", (_R, None), _set_payload),
    "write_output_integer_register": _b("address,value", (_R, _R), _reg("int", True)),
    "read_input_integer_register": _b("address", (_R,), _reg("int", False)),
    "write_output_float_register": _b("address,value", (_R, _R), _reg("float", True)),
    "read_input_float_register": _b("address", (_R,), _reg("float", False)),
    "write_output_boolean_register": _b("address,value", (_R, _R), _reg("bit", True)),
    "read_input_boolean_register": _b("address", (_R,), _reg("bit", False)),
    "norm": _b("a", (_R,), _norm),
    "sqrt": _b("f_", (_R,), _math1(math.sqrt)),
    "sin": _b("f_", (_R,), _math1(math.sin)),
    "cos": _b("f_", (_R,), _math1(math.cos)),
    "d2r": _b("f_", (_R,), _math1(math.radians)),
    "r2d": _b("f_", (_R,), _math1(math.degrees)),
    "floor": _b("f_", (_R,), _math1(lambda x: float(math.floor(x)))),
    "to_str": _b("f_", (_R,), lambda vm, n, f_: _str(f_)),
}
