"""Command groups of the ``quickhealth`` command line, one module each.

Each module defines ``register(subparsers) -> None``: it adds its sub-commands and sets
``func=callable(args) -> int`` on each parser.  A command function is a thin adapter: it
checks and converts its arguments (mm, degrees → SI), calls the application layer
(:mod:`quickhealth.station.services`) and prints the result.  ``register`` must stay cheap:
a command function imports its heavy modules (the fit's scipy, matplotlib, SQLAlchemy)
when it runs, each import saying why, so ``quickhealth --help`` stays fast.
"""

#: Which module registers each top-level command.  ``quickhealth CMD …`` imports only that
#: module (``run`` registers ``sim-controller``, whose arguments import the simulator: 0.1–0.2 s
#: a fit does not need); ``quickhealth --help`` and unknown commands import them all.
#: tests/station/test_cli_identify.py checks the table against the modules.
COMMAND_MODULES: dict[str, str] = {
    "check": "check",
    "demo": "demo",
    "diagnose": "diagnose",
    "examples": "examples",
    "twin": "diagnose",
    "compare": "compare",
    "identify": "identify",
    "import": "importing",
    "plan": "plan",
    "run": "run",
    "sim-controller": "run",
    "archive": "archive",
    "trend": "trend",
    "export": "export",
    "compensate": "compensate",
    "report": "report",
    "reprocess": "reprocess",
    "tui": "tui",
    "vision": "vision",
}
