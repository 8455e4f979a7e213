"""requirements.lock: read it, bootstrap uv from it, compare an environment with it.

The lock is written by ``uv pip compile`` (``make lock``, ``make upgrade``): one ``name==version``
line per distribution, an optional environment marker, and the sha256 of every file PyPI has for
that version.  This script needs only the standard library for ``bootstrap`` (it runs before
anything is installed); ``check`` uses ``packaging`` from the environment it checks.

    python tools/lockfile.py bootstrap uv     the lock's lines for uv (pip installs uv with them)
    python tools/lockfile.py core             the lock without the pins built from source against
                                              system libraries (FROM_SOURCE: make aravis installs
                                              them), for uv pip sync
    .venv/bin/python tools/lockfile.py check  installed distributions == the lock, and the lock
                                              satisfies every requirement in pyproject.toml;
                                              prints each difference, exit 1 when there is one
"""

from __future__ import annotations

import re
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
LOCK = ROOT / "requirements.lock"
PROJECT = "quickhealth"

#: Pins built from source against system libraries (PyGObject against libgirepository, pycairo
#: against cairo): ``make aravis`` installs them from the lock where the system allows it; an
#: environment without them is still the lock.
FROM_SOURCE = ("pygobject", "pycairo")

_PIN = re.compile(r"^([A-Za-z0-9][A-Za-z0-9._-]*)==(\S+?)\s*(?:;\s*(.*?))?\s*\\?$")


def normalize(name: str) -> str:
    """PEP 503 name: lower case, runs of ``-_.`` as one ``-``."""
    return re.sub(r"[-_.]+", "-", name).lower()


@dataclass(frozen=True)
class Pin:
    """One locked distribution: name, exact version, marker (or None), file hashes."""

    name: str
    version: str
    marker: str | None
    hashes: tuple[str, ...]
    text: str  # the lines of the lock for this pin, as written


def read_lock(path: Path = LOCK) -> list[Pin]:
    """Every pin of the lock, in file order."""
    pins: list[Pin] = []
    cur: list[str] = []
    for line in [*path.read_text(encoding="utf-8").splitlines(), ""]:
        if cur and not line.startswith((" ", "\t")):
            m = _PIN.match(cur[0])
            if m is None:
                raise ValueError(f"{path}: cannot read the line {cur[0]!r}")
            hashes = tuple(h for ln in cur for h in re.findall(r"--hash=(sha256:[0-9a-f]{64})", ln))
            pins.append(Pin(normalize(m[1]), m[2], m[3] or None, hashes, "\n".join(cur)))
            cur = []
        if line and not line.startswith(("#", " ", "\t")):
            cur = [line]
        elif cur and line.strip().startswith("--hash"):
            cur.append(line)
    return pins


def bootstrap(names: list[str], path: Path = LOCK) -> str:
    """The lock's lines (with hashes) for ``names``, a requirements file of their own."""
    want = {normalize(n) for n in names}
    found = [p for p in read_lock(path) if p.name in want]
    missing = want - {p.name for p in found}
    if missing:
        raise SystemExit(f"{path}: no pin for {', '.join(sorted(missing))} (run make lock)")
    return "\n".join(p.text for p in found) + "\n"


def core(path: Path = LOCK) -> str:
    """The lock as a requirements file, without the :data:`FROM_SOURCE` pins."""
    text = path.read_text(encoding="utf-8").splitlines()
    skip = {p.text.splitlines()[0] for p in read_lock(path) if p.name in FROM_SOURCE}
    out, drop = [], False
    for line in text:
        if line and not line.startswith((" ", "\t", "#")):
            drop = line in skip
        if not drop:
            out.append(line)
    return "\n".join(out) + "\n"


def applicable(pins: list[Pin]) -> dict[str, Pin]:
    """The pins whose marker holds in this interpreter, by name."""
    from packaging.markers import Marker

    out: dict[str, Pin] = {}
    for p in pins:
        if p.marker is None or Marker(p.marker).evaluate():
            out[p.name] = p
    return out


def installed() -> dict[str, str]:
    """Distributions importable by this interpreter (name -> version), the project excluded."""
    from importlib.metadata import distributions

    out: dict[str, str] = {}
    for d in distributions():
        name = normalize(d.metadata["Name"] or "")
        if name and name != PROJECT:
            out.setdefault(name, d.version)  # the first on sys.path is the one imported
    return out


def project_requirements(pyproject: Path = ROOT / "pyproject.toml") -> list[str]:
    """Every requirement of the project: dependencies and all optional dependencies."""
    proj = tomllib.loads(pyproject.read_text(encoding="utf-8"))["project"]
    reqs = list(proj.get("dependencies", []))
    for extra in proj.get("optional-dependencies", {}).values():
        reqs += extra
    return reqs


def differences(path: Path = LOCK) -> list[str]:
    """What differs between this environment, the lock and pyproject.toml (one line each)."""
    from packaging.requirements import Requirement

    pins = applicable(read_lock(path))
    have = installed()
    out: list[str] = []
    for name in sorted(set(pins) | set(have)):
        want = pins[name].version if name in pins else None
        got = have.get(name)
        if got is None and name in FROM_SOURCE:
            continue  # built where the system allows (make aravis): absent is the lock too
        if want != got:
            out.append(
                f"{name}: locked {want or 'absent'}, installed {got or 'absent'}"
                + ("" if want else " (not in the lock)")
                + ": rm .venv/.installed and make test syncs .venv to the lock"
            )
    for text in project_requirements():
        req = Requirement(text)
        if req.marker is not None and not req.marker.evaluate():
            continue
        pin = pins.get(normalize(req.name))
        if pin is None or not req.specifier.contains(pin.version, prereleases=True):
            locked = pin.version if pin else "nothing"
            out.append(f"pyproject.toml wants {text}, the lock has {locked} (run make lock)")
    return out


def main(argv: list[str]) -> int:
    """Command line (see the module docstring)."""
    if len(argv) >= 2 and argv[0] == "bootstrap":
        sys.stdout.write(bootstrap(argv[1:]))
        return 0
    if argv == ["core"]:
        sys.stdout.write(core())
        return 0
    if argv == ["check"]:
        diff = differences()
        for line in diff:
            print(line)
        if not diff:
            n = len(applicable(read_lock()))
            print(f"{n} distributions installed, exactly as locked in {LOCK.name}")
        return 1 if diff else 0
    sys.stderr.write(__doc__ or "")
    return 2


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
