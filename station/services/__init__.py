"""The application layer: what a user asks of the station, one typed function each.

Every door (the command line in :mod:`quickhealth.station.commands`, the technician's App
through :mod:`quickhealth.station.tui.facade`, fleet :mod:`quickhealth.station.reprocess` and
the demo) calls these functions and adds only its own words and arguments, so the same data
give the same files, figures and verdict whichever door they came through.  In the order of
the data:

- ``options``: :class:`~.options.FitOptions`, :class:`~.options.ReportOptions`: every default,
  once;
- ``fitting``: :func:`~.fitting.assess` and :func:`~.fitting.fit_folder`: the assessment of a
  run's measurements, and model.json, report.json, residuals.csv and the figures written
  atomically into its folder;
- ``report``: :func:`~.report.report_run`: report.html and the report's sections, the one
  verdict (:func:`quickhealth.station.reporting.verdict.judge`) and the ``run`` object in report.json;
- ``compensation``: :func:`~.compensation.compensate`: a robot program's joint targets
  corrected for the model, every refusal named;
- ``wam``: :func:`~.wam.wam_sign`: the sign of the WAM tracker's offset columns, from the data.
"""
