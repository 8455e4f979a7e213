"""``python -m quickhealth.station.sim``: run the UR controller simulator (see ``--help``).

Importing this module does nothing (the wheel test imports every module of the package).
"""

from .process import main

if __name__ == "__main__":
    raise SystemExit(main())
