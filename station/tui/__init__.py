"""The technician's terminal application (``quickhealth tui``): see ``app`` and ``facade``."""
