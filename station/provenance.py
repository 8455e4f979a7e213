"""What made a result: the quickhealth version and the numerical libraries' versions.

model.json, report.json and the run journal's ``start``/``resume`` records carry
``provenance()`` so an archived result says which software produced it (and the lock of that
version, ``requirements.lock``, gives back the exact environment).  Only the station calls this:
``identify`` and ``vision`` stay pure libraries that read no package metadata.

Library versions are those of the installed distributions (what ``pip install name==version``
gives back; OpenCV's includes its build number, e.g. 5.0.0.93), read from their metadata without
importing anything; a library found without metadata reports its module's ``__version__`` when
it is imported.
"""

from __future__ import annotations

import platform
import sys
from functools import cache
from importlib import metadata

PACKAGE = "quickhealth"

# key in provenance() -> (module, distributions that provide it, first installed wins)
_LIBRARIES: dict[str, tuple[str, tuple[str, ...]]] = {
    "numpy": ("numpy", ("numpy",)),
    "scipy": ("scipy", ("scipy",)),
    "opencv": (
        "cv2",
        (
            "opencv-contrib-python-headless",
            "opencv-contrib-python",
            "opencv-python-headless",
            "opencv-python",
        ),
    ),
    "pinocchio": ("pinocchio", ("pin",)),
}


@cache
def _dist_version(names: tuple[str, ...]) -> str:
    for name in names:
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return "not installed"


def software_version() -> str:
    """The installed quickhealth version (``unknown`` when run from a bare, uninstalled tree)."""
    return _dist_version((PACKAGE,)).replace("not installed", "unknown")


def version_number(text: str) -> str:
    """The version a record names, however it was written: ``"quickhealth 0.1.0"`` (the
    provenance's ``software``, the journal's start record) and ``"0.1.0"`` (the archive's
    ``software_version``) are the same version, ``"0.1.0"``."""
    t = str(text).strip()
    if t.lower().startswith(PACKAGE.lower() + " "):
        t = t[len(PACKAGE) + 1 :].strip()
    return t


def library_version(key: str) -> str:
    """Version of one of numpy, scipy, opencv, pinocchio (see the module docstring)."""
    module, dists = _LIBRARIES[key]
    v = _dist_version(dists)
    if v == "not installed":
        found = getattr(sys.modules.get(module), "__version__", None)
        v = found if isinstance(found, str) and found else v
    return v


def provenance() -> dict[str, str]:
    """Software and library versions, for the ``provenance`` object of a result file.

    Keys: ``software`` ("quickhealth X.Y.Z"), ``quickhealth``, ``python``, ``platform``,
    ``numpy``, ``scipy``, ``opencv``, ``pinocchio`` (all strings).
    """
    v = software_version()
    out = {
        "software": f"{PACKAGE} {v}",
        PACKAGE: v,
        "python": platform.python_version(),
        "platform": f"{sys.platform}-{platform.machine()}",
    }
    out.update({key: library_version(key) for key in _LIBRARIES})
    return out
