"""Only the simulation imports the twin: a static walk of every import a module can reach.

The simulator (:mod:`quickhealth.station.sim`: the controller simulator, the simulated world,
the pan-motor emulator and the simulated cameras) uses the drivers to build the simulated
cell; a driver importing it back would let simulator code (and its assumptions) into a run on
real hardware.  The digital twin (:mod:`quickhealth.identify.twin`, the simulated robot's
truth) is reached from the simulation only: not from a driver, the run, or the technician's
App on the real station.  The walk reads the source with :mod:`ast` (nothing is imported),
follows every ``import`` and ``from … import`` anywhere in a module (also those inside
functions) into the project's own modules, and fails naming the chain that reaches them.
"""

from __future__ import annotations

import ast
from functools import cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = {
    "quickhealth.identify": "identify",
    "quickhealth.vision": "vision",
    "quickhealth.station": "station",
}
SIM = "quickhealth.station.sim"
TWIN = "quickhealth.identify.twin"
DRIVERS = [
    "quickhealth.station.hardware.robot",
    "quickhealth.station.hardware.ur_client",
    "quickhealth.station.hardware.owner",
    "quickhealth.station.hardware.motor",
    "quickhealth.station.hardware.cameras",
    "quickhealth.station.hardware.cameras.registry",
    "quickhealth.station.hardware.cameras.genicam",
    "quickhealth.station.hardware.cameras.pylon",
    "quickhealth.station.hardware.cameras.files",
    "quickhealth.station.hardware.cameras.opencv",
    "quickhealth.station.hardware.urtypes",
    "quickhealth.station.hardware.target",
    "quickhealth.station.hardware.legs",
    "quickhealth.station.station",
    "quickhealth.station.run.loop",
]
# The App on the real cell (``quickhealth tui --robot-ip``): its dry run drives the plan on the
# simulator's arm model (sim.fake_robot), so it may reach the simulator but never the twin.
TUI_REAL = ["quickhealth.station.tui.app", "quickhealth.station.tui.facade"]


@cache
def source_of(module: str) -> Path | None:
    """The file of a project module (``X.py`` or ``X/__init__.py``), None when not ours."""
    for pkg, folder in PACKAGES.items():
        if module == pkg:
            base = ROOT / folder
        elif module.startswith(pkg + "."):
            base = ROOT / folder / Path(*module[len(pkg) + 1 :].split("."))
        else:
            continue
        for f in (base.with_suffix(".py"), base / "__init__.py"):
            if f.is_file():
                return f
        return None
    return None


@cache
def imports_of(module: str, path: Path) -> set[str]:
    """Every module ``path`` imports, absolute names (``from . import x`` gives both)."""
    is_pkg = path.name == "__init__.py"
    here = module if is_pkg else module.rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = here.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1])
                base = f"{base}.{node.module}" if node.module else base
            else:
                base = node.module or ""
            out.add(base)
            out.update(f"{base}.{a.name}" for a in node.names)  # a submodule, or just a name
    return out


def reach(start: str) -> dict[str, str]:
    """Every project module ``start`` reaches, each with the module that imported it."""
    seen = {start: ""}
    todo = [start]
    while todo:
        mod = todo.pop()
        path = source_of(mod)
        if path is None:
            continue
        for dep in imports_of(mod, path):
            # importing a.b.c runs a/__init__, a/b/__init__ too
            parts = dep.split(".")
            for i in range(2, len(parts) + 1):
                name = ".".join(parts[:i])
                if name not in seen and source_of(name) is not None:
                    seen[name] = mod
                    todo.append(name)
    return seen


def chain(seen: dict[str, str], mod: str) -> str:
    links = [mod]
    while seen.get(links[-1]):
        links.append(seen[links[-1]])
    return " <- ".join(links)


def test_the_walk_finds_what_it_must() -> None:
    """The walk itself works: the simulated cell does reach the simulator and the drivers."""
    seen = reach("quickhealth.station.sim.cell")
    assert "quickhealth.station.sim.process" in seen
    assert "quickhealth.station.hardware.robot" in seen
    assert "quickhealth.station.hardware.ur_client" in seen  # imported inside a function
    run = reach("quickhealth.station.run.loop")
    assert "quickhealth.station.hardware.robot" in run and "quickhealth.identify" in run


def test_no_driver_and_not_the_run_imports_the_simulator() -> None:
    bad = []
    for start in DRIVERS:
        assert source_of(start) is not None, start
        seen = reach(start)
        bad += [chain(seen, m) for m in seen if m == SIM or m.startswith(SIM + ".")]
    assert not bad, "the drivers must not import the simulator:\n" + "\n".join(bad)


def test_only_the_simulation_reaches_the_twin() -> None:
    """No driver, not the run, not the App on the real cell; the simulated cell does."""
    assert TWIN in reach("quickhealth.station.sim.cell")  # the walk sees it where it is
    assert TWIN in reach("quickhealth.station.tui.simulated")
    bad = []
    for start in DRIVERS + TUI_REAL:
        assert source_of(start) is not None, start
        seen = reach(start)
        bad += [chain(seen, m) for m in seen if m == TWIN]
    assert not bad, "only the simulation may import the digital twin:\n" + "\n".join(bad)


def test_world_emulator_and_simulated_cameras_live_in_the_simulation() -> None:
    for name in ("world", "motor_emulator", "cameras"):
        assert (ROOT / "station" / "sim" / f"{name}.py").is_file(), name
    for name in ("world", "motor_emulator"):
        assert not (ROOT / "station" / "hardware" / f"{name}.py").exists(), name
    for path in (ROOT / "station/hardware/cameras").glob("*.py"):
        assert "class SimStereoCamera" not in path.read_text(), path


def test_the_old_simulator_modules_are_gone_from_the_drivers() -> None:
    hw = ROOT / "station" / "hardware"
    for path in sorted(hw.rglob("*.py")):
        rel = path.relative_to(hw).with_suffix("")
        mod = ".".join(("quickhealth.station.hardware", *rel.parts)).removesuffix(".__init__")
        hits = [m for m in imports_of(mod, path) if m == SIM or m.startswith(SIM + ".")]
        assert not hits, f"{path.relative_to(ROOT)} imports {hits}"
