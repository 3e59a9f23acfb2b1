"""The package's import structure: every module imports, no module takes part in an import circle,
and the engine (physics, scenes, integrators) imports nothing of the application around it.

The graph is read from the source with ``ast``: every ``import`` / ``from ... import`` of a
taichi_soft module, at module level or inside a function (a function-level import that closes a
circle is still a circle; it only hides it until the function runs).
"""
import ast
import importlib
import pkgutil

import taichi_soft
from taichi_soft.paths import PACKAGE_DIR

# The application: command line (and its memory probe), gallery, interactive demo, rendering, benchmarks, task runner.
APP = ("cli", "peak_run", "commands", "gallery", "demo", "render", "bench", "tasks")
# Circles known today, each to be broken by its owner; the test fails when one is fixed too, so
# that it is removed here.
KNOWN_CIRCLES = set()


def _modules() -> dict:
    """module name -> (path, is_package) for every .py file of the package."""
    mods = {}
    for path in PACKAGE_DIR.rglob("*.py"):
        parts = list(path.relative_to(PACKAGE_DIR.parent).with_suffix("").parts)
        is_pkg = parts[-1] == "__init__"
        mods[".".join(parts[:-1] if is_pkg else parts)] = (path, is_pkg)
    return mods


def _imports(name: str, mods: dict) -> set:
    """The package modules ``name`` imports (``from pkg import sub`` counts as importing pkg.sub)."""
    path, is_pkg = mods[name]
    package = name if is_pkg else name.rpartition(".")[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.split(".")[0] == "taichi_soft"}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] != "taichi_soft":
                continue
            for a in node.names:
                sub = f"{target}.{a.name}"
                out.add(sub if sub in mods else target)
    return out & set(mods)


def _graph() -> dict:
    mods = _modules()
    return {name: _imports(name, mods) for name in mods}


def _circles(graph: dict) -> list[frozenset]:
    """Strongly connected components of more than one module (Tarjan). A module importing itself
    (tasks.py's Dask worker imports its own module by name, on the worker) is no circle."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = set()
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.add(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(frozenset(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def _is_app(name: str) -> bool:
    parts = name.split(".")
    return len(parts) > 1 and parts[1] in APP


def test_every_module_imports():
    names = [m.name for m in pkgutil.walk_packages(taichi_soft.__path__, "taichi_soft.")]
    assert set(names) | {"taichi_soft"} == set(_modules()), "a module the file scan and pkgutil disagree on"
    for name in names:
        importlib.import_module(name)


def test_each_registered_solver_lives_in_a_module_of_its_name():
    """A newcomer finds a method by its registered name: each implicit solver is the module of that
    name (its helpers in modules named for it), the explicit methods, a few lines each, share
    explicit.py."""
    from taichi_soft.sim.integrators import REGISTRY

    package = "taichi_soft.sim.integrators"
    for name, cls in REGISTRY.items():
        expected = f"{package}.implicit.{name}" if cls.implicit else f"{package}.explicit"
        assert cls.__module__ == expected, (name, cls.__module__)
    helpers = [m for m in _modules() if m.startswith(f"{package}.implicit.fast_mass_spring_")]
    assert helpers, "fast_mass_spring's matrix and L-BFGS modules carry its name"


def test_the_graph_reader_sees_relative_and_function_level_imports():
    """The checks below are only as good as the graph: known edges of each kind must be in it."""
    graph = _graph()
    assert "taichi_soft.sim.bodies" in graph["taichi_soft.sim.scene_validation"]  # from .bodies import BodySpec
    assert "taichi_soft.runtime" in graph["taichi_soft.sim.simulation"]  # from . import runtime
    assert "taichi_soft.sim.linalg" in graph["taichi_soft.sim.integrators.implicit.driver"]  # from ...linalg import PCG
    assert "taichi_soft.gallery" in graph["taichi_soft.commands.gallery"]  # inside cmd_gallery
    assert _circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [frozenset("abc")]
    assert _circles({"a": {"a", "b"}, "b": set()}) == []


def test_no_import_circles():
    assert set(_circles(_graph())) == KNOWN_CIRCLES


def test_engine_imports_nothing_of_the_application():
    graph = _graph()
    edges = sorted((a, b) for a, deps in graph.items() if not _is_app(a) for b in deps if _is_app(b))
    assert edges == []


# The application's layers, lowest first: a module may import its own layer and the ones below,
# never one above (the engine, every module outside these, is below them all).
LAYERS = (("render",), ("demo", "gallery", "bench"), ("commands",), ("cli", "peak_run"))


def _layer(name: str) -> int:
    parts = name.split(".")
    top = parts[1] if len(parts) > 1 else ""
    return next((i + 1 for i, layer in enumerate(LAYERS) if top in layer), 0)


def test_no_import_runs_up_a_layer():
    graph = _graph()
    up = sorted((a, b) for a, deps in graph.items() for b in deps if _layer(b) > _layer(a))
    assert up == []


def test_the_layer_check_sees_an_upward_import():
    assert _layer("taichi_soft.render.benchmark") < _layer("taichi_soft.bench.memory") < _layer("taichi_soft.cli")
    assert _layer("taichi_soft.sim.forces") == _layer("taichi_soft.timing") == 0


# A module a newcomer reads in one sitting holds one concept; past WARN_LINES it probably holds
# two, and past MAX_MODULE_LINES it is refused.
WARN_LINES, MAX_MODULE_LINES = 800, 1200


def test_modules_stay_readable():
    import warnings

    sizes = {name: len(path.read_text().splitlines()) for name, (path, _) in _modules().items()}
    long = {name: n for name, n in sizes.items() if n > MAX_MODULE_LINES}
    assert not long, long
    for name, n in sizes.items():
        if n > WARN_LINES:
            warnings.warn(f"{name} has {n} lines: does it hold more than one concept?", stacklevel=1)
