"""Package discovery for the three folders installed under ``quickhealth.*``.

pyproject.toml maps ``quickhealth.identify`` → ``identify/`` (and so on); this finds their
sub-packages so that nobody has to list them by hand.
"""

from setuptools import find_packages, setup

packages = []
for top in ("identify", "vision", "station"):
    packages.append(f"quickhealth.{top}")
    packages += [f"quickhealth.{top}.{sub}" for sub in find_packages(top)]

setup(packages=packages)
