"""Command groups of the ``quickhealth`` command line, one module each.

Each module defines ``register(subparsers) -> None``: it adds its sub-commands and sets
``func=callable(args) -> int`` on each parser.  ``register`` must stay cheap: import heavy
modules inside the command functions, so ``quickhealth --help`` stays fast.
"""
