"""Running a plan on the cell: the per-pose loop, its crash-safe journal and its locks.

One module per job (the stages of :func:`run_plan` in :mod:`.loop`'s docstring):

- :mod:`.loop` — :func:`run_plan`: open the run folder, pre-flight, the poses, the outputs;
- :mod:`.preflight` — every check before the first motion;
- :mod:`.runner` — one pose (move, settle, pan, capture, journal), the 7D measurement worker,
  the instrument self-check;
- :mod:`.settle` — the arm at rest from the joint stream;
- :mod:`.capture` — the quick detection check and the 7D measurement of a pair;
- :mod:`.sequence` — which pose comes next (the plan's loop, or the quick check's choice);
- :mod:`.journal` — the append-only, fsynced journal, for ``--resume``;
- :mod:`.outputs` — measurements.csv, run.json and calibration.json from the journal;
- :mod:`.lock` — one run drives the cell at a time, one writer per output;
- :mod:`.settings`, :mod:`.progress` — the run's tunables and its progress events.

The hardware a run drives is a :class:`~quickhealth.station.station.Station`.

Import from the module of each job (``from quickhealth.station.run.loop import run_plan``):
this package's ``__init__`` imports nothing, so the commands that only take a lock
(``from ..run import lock``) load neither OpenCV nor numpy.
"""
