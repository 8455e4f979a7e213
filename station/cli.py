"""quickhealth — quick health assessment of an industrial robot's accuracy.

Exit status: 0 success; 1 the assessment found a problem it was asked to flag;
2 bad input or usage; 3 hardware or runtime failure (an unexpected error is an
"internal error", exit 3, one line; --debug shows its traceback).
"""

from __future__ import annotations

import os

# The fits are many small dense solves: OpenBLAS threads only add contention on a small
# machine (measured ~10x slower on 2 busy cores).  Set before numpy loads; a user's own
# setting wins.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import importlib  # noqa: E402
import pkgutil  # noqa: E402
import sys  # noqa: E402
import traceback  # noqa: E402
from collections.abc import Sequence  # noqa: E402

from ..identify.errors import QuickhealthError  # noqa: E402
from . import commands  # noqa: E402
from .provenance import software_version  # noqa: E402


class _Parser(argparse.ArgumentParser):
    """argparse that exits with status 2 and one line on usage errors (the contract's code)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        sys.stderr.write(f"{self.prog}: error: {_one_line(message, 800, escape=True)}\n")
        raise SystemExit(2)


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser with every command group found in ``station/commands``; with ``command``
    (a top-level command name in ``commands.COMMAND_MODULES``) only the group that has it."""
    parser = _Parser(
        prog="quickhealth",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"quickhealth {software_version()}")
    parser.add_argument(
        "--debug",
        action="store_true",
        help="show the traceback of an internal error (exit 3) instead of one line "
        "(anywhere on the line: quickhealth trend cell3 --debug)",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    names = sorted(m.name for m in pkgutil.iter_modules(commands.__path__))
    if command in commands.COMMAND_MODULES:
        names = [commands.COMMAND_MODULES[command]]
    for name in names:
        mod = importlib.import_module(f"{commands.__name__}.{name}")
        register = getattr(mod, "register", None)
        if register is not None:
            register(sub)
    _finite_floats(parser)
    return parser


def _finite_floats(parser: argparse.ArgumentParser) -> None:
    """Every ``type=float`` option of every command accepts finite numbers only.

    ``--margin nan`` or ``--threshold-mm inf`` would otherwise pass argparse and silently
    change what a comparison means; they are usage errors (exit 2, one line).
    """
    from .formats import finite_float  # numpy: only once a command parses its numbers

    for action in parser._actions:
        if action.type is float:
            action.type = finite_float
        if isinstance(action, argparse._SubParsersAction):
            for sp in action.choices.values():
                _finite_floats(sp)


def _one_line(text: str, limit: int = 400, *, escape: bool = False) -> str:
    """``text`` on one line, cut to ``limit`` characters (a message never spans lines).
    ``escape``: a line break in it (a file name's) is shown as ``\\n``, else as a space."""
    t = str(text)
    if escape:
        t = t.replace("\r", "\\r").replace("\n", "\\n")
    s = " ".join(t.split())
    return s if len(s) <= limit else s[: limit - 1] + "…"


def _take_debug(argv: list[str]) -> tuple[list[str], bool]:
    """``argv`` without ``--debug``, and whether it was there: the flag is accepted anywhere
    (before or after the command's name), never after a ``--`` that ends the options."""
    end = argv.index("--") if "--" in argv else len(argv)
    head = [a for a in argv[:end] if a != "--debug"]
    return head + argv[end:], len(head) < end


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status (never raises, never exits 1 on a crash).

    Exit 1 is reserved for "the assessment flagged a problem".  A known error prints its one
    line (status 2 or 3); anything unexpected is an internal error: one line and status 3, the
    traceback only with ``--debug``.  Only the module of the command asked for is imported.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    argv, debug = _take_debug(argv)
    try:
        parser = build_parser(next((a for a in argv if not a.startswith("-")), None))
        args = parser.parse_args(argv)
        debug = debug or bool(getattr(args, "debug", False))
        func = getattr(args, "func", None)
        if func is None:
            parser.print_help()
            return 2
        status = int(func(args) or 0)
        return status
    except SystemExit as exc:  # argparse --help / usage errors, sys.exit() in a command
        code = exc.code
        if code is None:
            return 0
        if isinstance(code, int):
            return code
        sys.stderr.write(f"quickhealth: error: {_one_line(str(code))}\n")
        return 2
    except QuickhealthError as exc:
        if debug:
            traceback.print_exc()
        # one line per finding (each refused target of a program: formats.common.findings),
        # each on one line; a line break inside one (a file name's) never splits it
        found = getattr(exc, "findings", None) or [str(exc)]
        lines = [_one_line(x, escape=True) for x in found if str(x).strip()] or ["(no message)"]
        if len(lines) > 50:
            lines = lines[:49] + [f"... and {len(lines) - 49} more"]
        sys.stderr.write("".join(f"quickhealth: error: {x}\n" for x in lines))
        return exc.exit_status
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM/SIGHUP (workers.Terminated)
        sys.stderr.write(f"quickhealth: {str(exc) or 'interrupted'}\n")
        return 3
    except MemoryError:
        sys.stderr.write(
            "quickhealth: error: out of memory (the input is too large for this machine)\n"
        )
        return 3
    except RecursionError:
        sys.stderr.write("quickhealth: error: input nested too deeply (recursion limit)\n")
        return 2
    except BrokenPipeError:  # the reader of stdout went away (`… | head`): nothing to say
        try:  # further writes (the interpreter's flush at exit) go nowhere
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        except (OSError, ValueError):
            pass
        return 0
    except OSError as exc:
        if debug:
            traceback.print_exc()
        where = f"{exc.filename}: " if exc.filename else ""
        what = exc.strerror or type(exc).__name__
        sys.stderr.write(f"quickhealth: error: {_one_line(where + what)}\n")
        return 3
    except Exception as exc:  # noqa: BLE001 - the contract: one line, exit 3, never exit 1
        if debug:
            traceback.print_exc()
        sys.stderr.write(
            f"quickhealth: internal error: {type(exc).__name__}: {_one_line(str(exc), 300)} "
            "(run with --debug for the traceback)\n"
        )
        return 3


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
