"""``python -m quickhealth.station.sim``: run the UR controller simulator (see ``--help``)."""

from .process import main

raise SystemExit(main())
