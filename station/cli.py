"""quickhealth — quick health assessment of an industrial robot's accuracy.

Exit status: 0 success; 1 the assessment found a problem it was asked to flag;
2 bad input or usage; 3 hardware or runtime failure.
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
from collections.abc import Sequence  # noqa: E402

from quickhealth.identify.errors import QuickhealthError  # noqa: E402

from . import commands  # noqa: E402


class _Parser(argparse.ArgumentParser):
    """argparse that exits with status 2 and one line on usage errors (the contract's code)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        sys.stderr.write(f"{self.prog}: error: {message}\n")
        raise SystemExit(2)


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser with every command group found in ``station/commands``; with ``command``
    (a top-level command name in ``commands.COMMAND_MODULES``) only the group that has it."""
    parser = _Parser(
        prog="quickhealth",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
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
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status (never raises for known errors)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(argv[0] if argv else None)
    args = parser.parse_args(argv)
    func = getattr(args, "func", None)
    if func is None:
        parser.print_help()
        return 2
    try:
        return int(func(args) or 0)
    except QuickhealthError as exc:
        sys.stderr.write(f"quickhealth: error: {exc}\n")
        return exc.exit_status
    except KeyboardInterrupt:
        sys.stderr.write("quickhealth: interrupted\n")
        return 3


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
