"""quickhealth.station — hardware, runs, archive, command line and the technician TUI.

Depends on ``quickhealth.identify`` and ``quickhealth.vision``, never the reverse.
The command line lives in ``cli`` with one module per command group in ``commands/``.
"""
