"""The layers depend downward only (docs/interfaces.md §1, README "Source layout").

The import graph of the installed packages, read from their source (every ``import``,
also inside functions; not those under ``if TYPE_CHECKING:``):

* packages: ``damper_emulator`` (the damper) ← ``ride_sim`` (the quarter car) ←
  ``can_bridge`` (the CAN side) ← ``damper_hil`` (the application: CLI, demo, reports);
  nothing imports a package above its own;
* no module imports itself back through others (no cycle; a submodule's dependence on its
  own package ``__init__`` does not count: Python imports it first anyway);
* the physics and data cores import no ROS, no plotting and no application code, directly
  or through other modules.
"""

from __future__ import annotations

import ast
import functools
import importlib
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import pytest

#: bottom to top; a package may import only those before it
PACKAGES = ("damper_emulator", "ride_sim", "can_bridge", "damper_hil")
#: the cores: modules (and sub-packages) that must stay free of ROS, plots and the app
CORES = ("damper_emulator.errors", "damper_emulator.outputs", "damper_emulator.params",
         "damper_emulator.blas",
         "damper_emulator.schema",
         "damper_emulator.model", "damper_emulator.realtime", "damper_emulator.bag",
         "damper_emulator.force_message", "damper_emulator.acquisition",
         "damper_emulator.dyno.measured", "damper_emulator.dyno.measured_bag",
         "damper_emulator.dyno.limits", "damper_emulator.dyno.protocols",
         "damper_emulator.identify.quasi_static", "damper_emulator.identify.valves",
         "damper_emulator.identify.fitting", "damper_emulator.diagnose.joint",
         "damper_emulator.diagnose.candidates", "damper_emulator.diagnose.selection",
         "damper_emulator.diagnose.base", "damper_emulator.diagnose.outcome",
         "damper_emulator.diagnose.tasks", "damper_emulator.diagnose.session",
         "damper_emulator.diagnose.pool", "damper_emulator.diagnose.rounds",
         "damper_emulator.diagnose.interference", "damper_emulator.diagnose.series",
         "damper_emulator.diagnose.series_stage", "damper_emulator.diagnose.statistics",
         "damper_emulator.diagnose.term_trust",
         "damper_emulator.diagnose.measurement", "damper_emulator.diagnose.truth_series",
         "ride_sim.quarter_car", "ride_sim.road", "ride_sim.road_spectra",
         "ride_sim.road_synthesis", "ride_sim.road_features", "ride_sim.road_envelope",
         "ride_sim.road_csv", "ride_sim.road_speed", "ride_sim.iso2631", "ride_sim.params",
         "ride_sim.frequency_domain", "ride_sim.metrics", "ride_sim.dampers",
         "ride_sim.many", "ride_sim.tuning", "ride_sim.loop_delay", "ride_sim.hybrid",
         "can_bridge.codec", "can_bridge.bus", "can_bridge.crc", "can_bridge.dbc")
#: what a core may not reach
FORBIDDEN = ("rclpy", "matplotlib", "damper_hil", "damper_emulator.ros", "ride_sim.node",
             "can_bridge.node", "launch")


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        root = Path(importlib.import_module(pkg).__file__).parent
        for f in root.rglob("*.py"):
            parts = f.relative_to(root.parent).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            out[name] = f
    return out


def _type_checking_lines(tree: ast.AST) -> set[int]:
    lines: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            for child in node.body:
                lines.update(range(child.lineno, (child.end_lineno or child.lineno) + 1))
    return lines


MODULES = _modules()


@functools.cache
def _tree(name: str) -> ast.Module:
    """A module's syntax tree, parsed once (when a test first asks: the graphs are built
    by the worker that runs these tests, not by every collecting process)."""
    return ast.parse(MODULES[name].read_text(encoding="utf-8"))


@functools.cache
def _graph(type_checking: bool = False) -> tuple[dict[str, set[str]], dict[str, set[str]]]:
    """``(internal, external)``: per module, the project modules and the top-level
    third-party modules it imports (with ``type_checking``, those for the type checker
    only too)."""
    mods = MODULES
    internal: dict[str, set[str]] = defaultdict(set)
    external: dict[str, set[str]] = defaultdict(set)
    for name, path in mods.items():
        tree = _tree(name)
        skip = set() if type_checking else _type_checking_lines(tree)
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node in ast.walk(tree):
            if not isinstance(node, (ast.Import, ast.ImportFrom)) or node.lineno in skip:
                continue
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                if node.level:
                    base = package.split(".")[:len(package.split(".")) - node.level + 1]
                    mod = ".".join(base + ([node.module] if node.module else []))
                else:
                    mod = node.module or ""
                # ``from P import x``: the submodule P.x if there is one, else P
                targets = [f"{mod}.{a.name}" if f"{mod}.{a.name}" in mods else mod
                           for a in node.names]
            for t in targets:
                if t.split(".")[0] not in PACKAGES:
                    external[name].add(t)
                    continue
                while t not in mods and "." in t:
                    t = t.rpartition(".")[0]
                # a module's own ancestors are imported first by Python in any case
                if t != name and not name.startswith(t + "."):
                    internal[name].add(t)
    return internal, external



def _imports() -> dict[str, set[str]]:
    """Per module, the project modules it imports."""
    return _graph()[0]


def _external() -> dict[str, set[str]]:
    """Per module, the third-party modules it imports."""
    return _graph()[1]


def _typed_imports() -> dict[str, set[str]]:
    """:func:`_imports` with the imports for the type checker: a reader follows those too."""
    return _graph(type_checking=True)[0]


def test_packages_depend_downward_only():
    bad = sorted(f"{a} imports {b}" for a, deps in _imports().items() for b in deps
                 if PACKAGES.index(b.split(".")[0]) > PACKAGES.index(a.split(".")[0]))
    assert not bad, "\n".join(bad)


def test_no_module_imports_itself_back():
    """Not even through an import for the type checker: a module a reader must understand
    before the one it imports is a cycle all the same."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles: list[list[str]] = []
    graph = _typed_imports()

    def visit(v: str) -> None:         # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in sorted(set(graph) | {w for d in graph.values() for w in d}):
        if v not in index:
            visit(v)
    assert not cycles, cycles


def _private_imports() -> list[str]:
    """Every use of another project module's private name (``_x``): ``from m import _x``
    and ``m._x`` where ``m`` is a project module."""
    found = []
    for name in MODULES:
        tree = _tree(name)
        modules: dict[str, str] = {}        # local name → the project module it is
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for a in node.names:
                    if a.name in MODULES:
                        modules[a.asname or a.name.split(".")[0]] = (
                            a.name if a.asname else a.name.split(".")[0])
            elif isinstance(node, ast.ImportFrom) and node.module in MODULES:
                for a in node.names:
                    if a.name.startswith("_") and not a.name.startswith("__") \
                            and node.module != name:
                        found.append(f"{name}:{node.lineno} from {node.module} import "
                                     f"{a.name}")
                    if f"{node.module}.{a.name}" in MODULES:
                        modules[a.asname or a.name] = f"{node.module}.{a.name}"
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) \
                    and node.value.id in modules and node.attr.startswith("_") \
                    and not node.attr.startswith("__") and modules[node.value.id] != name:
                found.append(f"{name}:{node.lineno} {modules[node.value.id]}.{node.attr}")
    return sorted(found)


def test_no_module_uses_another_modules_private_names():
    """What one module needs of another is published under a public name."""
    bad = _private_imports()
    assert not bad, "\n".join(bad)


def _reach(start: str) -> set[str]:
    seen, todo = set(), [m for m in MODULES if m == start or m.startswith(start + ".")]
    while todo:
        m = todo.pop()
        if m in seen:
            continue
        seen.add(m)
        todo.extend(_imports().get(m, ()))
    return seen


@pytest.mark.parametrize("core", CORES)
def test_cores_reach_no_ros_plots_or_application(core):
    reached = _reach(core)
    assert reached, f"{core}: no such module"
    bad = sorted({f"{m} → {x}" for m in reached
                  for x in (*_imports().get(m, ()), *_external().get(m, ()))
                  if any(x == f or x.startswith(f + ".") for f in FORBIDDEN)})
    assert not bad, "\n".join(bad)


def test_the_graph_is_real():
    """The walk sees what we know is there (guards against a walk that finds nothing)."""
    assert "damper_emulator.model.compressible" in _imports()["damper_emulator.replay"]
    assert "rclpy" in _external()["damper_emulator.ros.emulator"]
    assert any(d.startswith("ride_sim") for d in _imports()["damper_hil.hil_demo"])


#: what the command line's start (its parser, every subcommand's options and help) must
#: not import: each subcommand imports its own work when it runs, so that a user error, a
#: ``--help`` and every node's start do not pay for the diagnosis, Dask, plots, ROS or CAN
#: (python-can imports asammdf and pandas for its MF4 writer: 0.4 s)
START_FORBIDDEN = ("damper_emulator.diagnose", "damper_emulator.identify", "scipy.signal",
                   "scipy.ndimage", "scipy.optimize", "dask", "distributed", "matplotlib",
                   "rclpy", "can", "asammdf", "pandas")


def test_the_command_line_starts_without_the_heavy_modules():
    code = ("import sys, damper_hil.cli as c; c.build_parser(); "
            "print('\\n'.join(sorted(sys.modules)))")
    loaded = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True,
                            text=True).stdout.split()
    assert "damper_hil.cli.fleet_example" in loaded  # the walk sees the subcommands
    bad = [m for m in loaded if any(m == f or m.startswith(f + ".") for f in START_FORBIDDEN)]
    assert not bad, bad


def test_figures_come_from_the_one_plotting_helper():
    """Every figure is made by :func:`damper_emulator.dyno.plots.new_figure` and saved by
    its ``save`` (the Agg canvas, printable labels): no module drives pyplot, whose global
    backend and figure registry are not thread-safe and not headless by default."""
    bad = sorted(m for m, deps in _external().items()
                 if any(d == "matplotlib.pyplot" or d.startswith("matplotlib.pyplot.")
                        or d == "matplotlib.use" for d in deps))
    assert not bad, bad
    assert "matplotlib.figure" in _external()["damper_emulator.dyno.plots"]


def test_the_can_packages_lazy_names_are_its_exports_and_resolve():
    """``can_bridge`` imports its modules when a name is asked for: every exported name
    has a home there, and each resolves to the object of its module."""
    import importlib

    import can_bridge

    assert set(can_bridge._HOME) == set(can_bridge.__all__)
    for name, home in can_bridge._HOME.items():
        module = importlib.import_module(f"can_bridge.{home}")
        assert getattr(can_bridge, name) is getattr(module, name), name
