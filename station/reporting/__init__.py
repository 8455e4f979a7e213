"""What a run comes to, for people: the one verdict, the ISO 9283 figures and the report page.

- :mod:`.verdict`   the one health verdict (healthy, degraded, flagged) every door shows
- :mod:`.iso9283`   ISO 9283 pose accuracy and repeatability at poses visited repeatedly
- :mod:`.page`      the report's sections and the self-contained HTML page

Gathering a run folder's findings is the report service's job
(:mod:`quickhealth.station.services.report`).
"""
