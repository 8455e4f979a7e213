"""Command groups of the ``quickhealth`` command line, one module each.

Each module defines ``register(subparsers) -> None``: it adds its sub-commands and sets
``func=callable(args) -> int`` on each parser.  ``register`` must stay cheap: import heavy
modules inside the command functions, so ``quickhealth --help`` stays fast.
"""

#: Which module registers each top-level command.  ``quickhealth CMD …`` imports only that
#: module (``run`` registers ``sim-controller``, whose arguments import the simulator: 0.1–0.2 s
#: a fit does not need); ``quickhealth --help`` and unknown commands import them all.
#: tests/station/test_cli_identify.py checks the table against the modules.
COMMAND_MODULES: dict[str, str] = {
    "demo": "demo",
    "diagnose": "diagnose",
    "twin": "diagnose",
    "compare": "diagnose",
    "identify": "identify",
    "import": "importing",
    "plan": "plan",
    "run": "run",
    "sim-controller": "run",
    "archive": "trend",
    "trend": "trend",
    "export": "trend",
    "compensate": "trend",
    "report": "trend",
    "reprocess": "trend",
    "tui": "tui",
    "vision": "vision",
}
