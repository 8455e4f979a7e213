"""One exception tree for the whole product.

``QuickhealthError`` is the root.  ``InputError`` (exit status 2) is bad input a user can fix:
the message is one line that says what and where.  ``HardwareError`` (exit status 3) is a
hardware or runtime failure.  The command line (``quickhealth.station.cli``) prints the one
line for these and keeps the traceback for anything else.
"""

from __future__ import annotations


class QuickhealthError(Exception):
    """Root of every error the product raises on purpose."""

    exit_status = 3


class InputError(QuickhealthError, ValueError):
    """Bad input or usage: a file, a column, an option.  Exit status 2."""

    exit_status = 2


class HardwareError(QuickhealthError, RuntimeError):
    """A robot, motor, camera or simulator failed or refused.  Exit status 3."""

    exit_status = 3
