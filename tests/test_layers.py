"""No module imports upward across the layers (ARCHITECTURE.md, "Layers").

    base  <  rig, emulator  <  integration        (packages: bracketry_base < bracketry_rig, bracketry_emulator <
                                                   bracketry)

Each layer is a top-level package and folder of its own (:data:`LAYER_TABLE`): a package's imports, lazy ones
included, go down the table only, and no package imports another that imports it back (:func:`package_imports`).

- **base**: what both packages share, on the core dependencies alone (OpenCV only where a PNG is written): errors,
  progress, paths, output checks, the CLI's option types, the PNG codec (``bracketry_base.png``), the recording format
  with its reader and checker (``bracketry_base.recording``; the rig's recorder and session are
  ``bracketry_rig.recording``) and the stereo calibration library (``bracketry_base.calibration``: board,
  detection, coverage, solve; numpy and OpenCV only).
- **rig** (``bracketry_rig``) and **emulator** (``bracketry_emulator``) are peers: neither imports the other,
  so a rig runs without the emulator's dependencies and the emulator never reaches into the rig.
- **integration**: what joins them: the simulated rig (``bracketry.sim``), the demo, the test harnesses and the CLI
  (``bracketry.cli``; its ``COMMANDS`` name the emulator's commands as strings and load them when used).

Inside the emulator its sub-packages stand on floors (:data:`EMULATOR_FLOORS`): a module imports its own sub-package
and lower floors, never a neighbour on its floor nor a higher floor (trajectory files below both metrics and SLAM,
metrics and VO apart, the report below the benchmark).

The benchmark scripts (``benchmarks/``) are a layer above all: they may import every layer, none imports them.

Every import statement counts, module-level or inside a function (a lazy import runs upward just the same), parsed
with :mod:`ast` from the source of both packages and the benchmark scripts.

No two files import each other, directly or around a longer loop (:func:`import_cycles`): every import that runs
counts, lazy ones included (a lazy import hides a cycle from Python, not from the reader); imports under ``if
TYPE_CHECKING:`` do not run and do not count.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

from bracketry_base.paths import repo_root

BASE, RIG, EMULATOR, INTEGRATION, BENCHMARKS = "base", "rig", "emulator", "integration", "benchmarks"
#: the layers each layer may import (itself included)
MAY_IMPORT: dict[str, set[str]] = {
    BASE: {BASE},
    RIG: {BASE, RIG},
    EMULATOR: {BASE, EMULATOR},
    INTEGRATION: {BASE, RIG, EMULATOR, INTEGRATION},
    BENCHMARKS: {BASE, RIG, EMULATOR, INTEGRATION, BENCHMARKS},
}
#: top-level package -> layer: each layer is a package (and a folder) of its own, so a module's layer is its package's
LAYER_TABLE: dict[str, str] = {
    "bracketry_base": BASE,
    "bracketry_rig": RIG,
    "bracketry_emulator": EMULATOR,
    "bracketry": INTEGRATION,
    "benchmarks": BENCHMARKS,
}
#: the emulator's sub-packages and top-level modules by floor (0 = ground); every module of the emulator is on one
EMULATOR_FLOORS: dict[str, int] = {
    "bracketry_emulator.defaults": 0, "bracketry_emulator.extensions": 0, "bracketry_emulator.stages": 0,
    "bracketry_emulator.runtime_policy": 0, "bracketry_emulator.trajectory_io": 0, "bracketry_emulator.crf": 0,
    "bracketry_emulator.features": 0, "bracketry_emulator.stats": 0,
    "bracketry_emulator.dataset": 1, "bracketry_emulator.synth": 1, "bracketry_emulator.option_table": 1,
    "bracketry_emulator.emulation": 2, "bracketry_emulator.vo": 2, "bracketry_emulator.metrics": 2,
    "bracketry_emulator.ae": 3, "bracketry_emulator.accuracy": 3, "bracketry_emulator.slam": 3,
    "bracketry_emulator.report": 3,
    "bracketry_emulator.benchmark": 4, "bracketry_emulator.envs": 4,
    "bracketry_emulator.cli": 5,
}
#: the source folder of each package
PACKAGES = {"bracketry_base": Path("host/bracketry_base"), "bracketry_rig": Path("host/bracketry_rig"),
            "bracketry_emulator": Path("emulator/bracketry_emulator"), "bracketry": Path("host/bracketry"),
            "benchmarks": Path("benchmarks")}


@dataclass(frozen=True)
class Import:
    module: str  # the importing module
    target: str  # the module imported (``from a import b``: ``a.b`` when that is a module, else ``a``)
    line: int
    lazy: bool  # inside a function or class, not at module level
    typing_only: bool = False  # under ``if TYPE_CHECKING:``: never runs


def _longest(name: str, table: dict[str, object]) -> str | None:
    parts = name.split(".")
    for n in range(len(parts), 0, -1):
        key = ".".join(parts[:n])
        if key in table:
            return key
    return None


def layer_of(module: str, table: dict[str, str] = LAYER_TABLE) -> str | None:
    key = _longest(module, table)  # type: ignore[arg-type]
    return None if key is None else table[key]


def floor_of(module: str, floors: dict[str, int] = EMULATOR_FLOORS) -> int:
    key = _longest(module, floors)  # type: ignore[arg-type]
    return 0 if key is None else floors[key]


def module_sources(root: Path, packages: dict[str, Path] = PACKAGES) -> dict[str, tuple[Path, bool]]:
    """Module name -> (source file, is a package's ``__init__``) for every .py file of ``packages``."""
    out = {}
    for pkg, folder in packages.items():
        for f in sorted((root / folder).rglob("*.py")):
            if "__pycache__" in f.parts:
                continue
            parts = (pkg, *f.relative_to(root / folder).with_suffix("").parts)
            is_init = parts[-1] == "__init__"
            out[".".join(parts[:-1] if is_init else parts)] = (f, is_init)
    return out


def imports_of(module: str, source: str, is_init: bool, known: set[str]) -> list[Import]:
    """Every import statement of ``module`` (module level and inside functions) naming a module of ``known``'s
    packages, relative imports resolved."""
    tops = {k.split(".")[0] for k in known}
    tree = ast.parse(source)
    lazy_lines: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef | ast.Lambda):
            for inner in ast.walk(node):
                if isinstance(inner, ast.Import | ast.ImportFrom):
                    lazy_lines.add(id(inner))
    typing_only: set[int] = set()
    for node in ast.walk(tree):
        test = node.test if isinstance(node, ast.If) else None
        if test is not None and "TYPE_CHECKING" in ast.unparse(test):
            for inner in node.body:
                typing_only.update(id(n) for n in ast.walk(inner) if isinstance(n, ast.Import | ast.ImportFrom))
    found = []
    for node in ast.walk(tree):
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".") if is_init else module.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)]
                pkg = ".".join(base + ([node.module] if node.module else []))
            else:
                pkg = node.module or ""
            targets = [f"{pkg}.{a.name}" if f"{pkg}.{a.name}" in known else pkg for a in node.names]
        for t in dict.fromkeys(targets):
            if t.split(".")[0] in tops:
                found.append(Import(module, t, node.lineno, id(node) in lazy_lines,  # type: ignore[attr-defined]
                                    id(node) in typing_only))
    return found


def upward_imports(modules: dict[str, tuple[str, bool]], table: dict[str, str] = LAYER_TABLE,
                   floors: dict[str, int] = EMULATOR_FLOORS) -> list[str]:
    """One line per import that runs upward across the layers (or up the emulator's floors), and per module that
    has no layer. ``modules``: name -> (source text, is a package's ``__init__``)."""
    known = set(modules)
    problems = []
    for module, (source, is_init) in sorted(modules.items()):
        mine = layer_of(module, table)
        if mine is None:
            problems.append(f"{module}: in no layer (add it to the layer table)")
            continue
        if mine == EMULATOR and "." in module and _longest(module, floors) is None:  # type: ignore[arg-type]
            problems.append(f"{module}: on no floor of the emulator (add it to the floors)")
        for imp in imports_of(module, source, is_init, known):
            theirs = layer_of(imp.target, table)
            how = "lazy import" if imp.lazy else "import"
            where = f"{module}:{imp.line}: {how} of {imp.target}"
            if theirs is None:
                problems.append(f"{where}: in no layer")
            elif theirs not in MAY_IMPORT[mine]:
                problems.append(f"{where}: the {mine} layer may not import the {theirs} layer")
            elif mine == theirs == EMULATOR:
                unit, other = _longest(module, floors), _longest(imp.target, floors)  # type: ignore[arg-type]
                up, down = floor_of(module, floors), floor_of(imp.target, floors)
                if unit != other and down > up:
                    problems.append(f"{where}: floor {up} may not import floor {down} of the emulator")
                elif unit != other and down == up:
                    problems.append(f"{where}: {unit} may not import its neighbour {other} on floor {up}")
    return problems


def package_imports(modules: dict[str, tuple[str, bool]]) -> dict[str, set[str]]:
    """Top-level package -> the other top-level packages its modules import (module level or lazy; not
    ``TYPE_CHECKING``). ``modules``: name -> (source, is ``__init__``)."""
    known = set(modules)
    out: dict[str, set[str]] = {m.split(".")[0]: set() for m in modules}
    for module, (source, is_init) in modules.items():
        mine = module.split(".")[0]
        for imp in imports_of(module, source, is_init, known):
            theirs = imp.target.split(".")[0]
            if not imp.typing_only and theirs != mine:
                out[mine].add(theirs)
    return out


def package_problems(graph: dict[str, set[str]], table: dict[str, str] = LAYER_TABLE) -> list[str]:
    """One line per package import that does not go down the layer table (a peer or a higher layer), and per
    pair of packages that import each other."""
    problems = []
    for pkg, targets in sorted(graph.items()):
        for t in sorted(targets):
            mine, theirs = table.get(pkg), table.get(t)
            if mine is None or theirs is None or theirs not in MAY_IMPORT[mine] or mine == theirs:
                problems.append(f"{pkg} imports {t}: the {mine} layer may not import the {theirs} layer")
            if pkg in graph.get(t, set()) and pkg < t:
                problems.append(f"{pkg} and {t} import each other")
    return problems


def import_cycles(modules: dict[str, tuple[str, bool]]) -> list[list[str]]:
    """The import cycles between files: each group of modules (sorted; groups sorted) that reach each other by
    imports that run (module level or lazy; not ``TYPE_CHECKING``). ``modules``: name -> (source, is ``__init__``).
    An import names the file it imports (``from a import b``: ``a.b`` when that is a module, else ``a``); the parent
    packages Python runs first are not counted."""
    known = set(modules)
    graph: dict[str, set[str]] = {m: set() for m in modules}
    for module, (source, is_init) in modules.items():
        for imp in imports_of(module, source, is_init, known):
            if not imp.typing_only and imp.target in known and imp.target != module:
                graph[module].add(imp.target)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    groups: list[list[str]] = []

    def visit(root: str) -> None:  # Tarjan's strongly connected components, iterative
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                group = []
                while True:
                    m = stack.pop()
                    on_stack.discard(m)
                    group.append(m)
                    if m == node:
                        break
                if len(group) > 1:
                    groups.append(sorted(group))

    for m in sorted(graph):
        if m not in index:
            visit(m)
    return sorted(groups)


def _tree_modules() -> dict[str, tuple[str, bool]]:
    return {m: (f.read_text(), init) for m, (f, init) in module_sources(repo_root()).items()}


def test_no_module_imports_upward() -> None:
    modules = _tree_modules()
    assert len(modules) > 150
    assert upward_imports(modules) == []


def test_packages_import_only_down_the_table() -> None:
    """At package level: each layer's package imports only packages of lower layers, none imports another that
    imports it back, and every package of the tree has a layer."""
    graph = package_imports(_tree_modules())
    assert set(graph) == set(LAYER_TABLE) == set(PACKAGES)
    assert package_problems(graph) == []
    assert graph["bracketry_base"] == set()
    assert graph["bracketry_rig"] == graph["bracketry_emulator"] == {"bracketry_base"}


def test_package_problems_are_found() -> None:
    """On synthetic package graphs: an import up, one across to a peer and a pair importing each other are
    reported; imports down are not."""
    assert package_problems({"bracketry_base": set(), "bracketry_rig": {"bracketry_base"},
                             "bracketry": {"bracketry_rig", "bracketry_base"}}) == []
    assert package_problems({"bracketry_base": {"bracketry_rig"}, "bracketry_rig": {"bracketry_base"}}) == [
        "bracketry_base imports bracketry_rig: the base layer may not import the rig layer",
        "bracketry_base and bracketry_rig import each other"]
    assert package_problems({"bracketry_rig": {"bracketry_emulator"}, "bracketry_emulator": set()}) == [
        "bracketry_rig imports bracketry_emulator: the rig layer may not import the emulator layer"]
    lazy = {"bracketry_base": ("", True), "bracketry_base.png": ("def f():\n    import bracketry.cli\n", False),
            "bracketry": ("", True), "bracketry.cli": ("", True)}
    assert package_imports(lazy) == {"bracketry_base": {"bracketry"}, "bracketry": set()}


def test_layer_table_names_only_existing_modules() -> None:
    """A renamed or removed module must leave the tables too (else an entry silently stops applying)."""
    known = set(_tree_modules())
    stale = [name for name in [*LAYER_TABLE, *EMULATOR_FLOORS]
             if name not in known and not any(k.startswith(name + ".") for k in known)]
    assert stale == []


def test_upward_imports_are_found() -> None:
    """On a synthetic module set: each kind of upward import is reported (module level, lazy, relative, and
    ``from package import module``), imports down or across within a layer are not."""
    modules = {
        "bracketry": ("", True),
        "bracketry_base.errors": ("", False),
        "bracketry_base.recording.reader": ("from bracketry_base.errors import BracketryError\n", False),
        "bracketry_rig.export.borealhdr": (  # rig -> emulator, lazily
            "from bracketry_base.recording.reader import RecordingReader\n"
            "def f():\n    from bracketry_emulator.emulation.writer import write_png\n", False),
        "bracketry.sim.rig": ("from bracketry_emulator.synth import World\n", False),  # integration: allowed
        "bracketry_rig.cameras.fake": ("from bracketry.sim import rig\n", False),  # rig -> integration
        "bracketry_emulator": ("", True),
        "bracketry_emulator.trajectory_io": ("", False),
        "bracketry_emulator.emulation": ("", True),
        "bracketry_emulator.emulation.writer": ("from bracketry_base.errors import BracketryError\n", False),
        "bracketry_emulator.synth": ("", True),
        "bracketry_emulator.vo": ("", True),
        "bracketry_emulator.vo.orbslam": (  # floor 2 -> its neighbour metrics on floor 2: refused; floor 0: allowed
            "from bracketry_emulator import trajectory_io\nfrom ..metrics.evaluate import x\n", False),
        "bracketry_emulator.metrics": ("", True),
        "bracketry_emulator.metrics.evaluate": ("", False),
        "bracketry_emulator.report": ("", True),
        "bracketry_emulator.report.write": (  # floor 3 -> floor 4, lazily and relative
            "class W:\n    def g(self):\n        from ..benchmark.slam import describe\n", False),
        "bracketry_emulator.benchmark": ("", True),
        "bracketry_emulator.benchmark.slam": ("", False),
        "bracketry_emulator.dataset": ("", True),
        "bracketry_emulator.dataset.mcap_reader": (  # emulator -> rig
            "from bracketry_base.recording import reader\nimport bracketry_rig.daemon.rig\n", False),
        "bracketry_rig.daemon.rig": ("", False),
    }
    problems = upward_imports(modules)
    assert [p.split(": ")[0] for p in problems] == [
        "bracketry_emulator.dataset.mcap_reader:2",
        "bracketry_emulator.report.write:3",
        "bracketry_emulator.vo.orbslam:2",
        "bracketry_rig.cameras.fake:1",
        "bracketry_rig.export.borealhdr:3",
    ], problems
    assert "lazy import of bracketry_emulator.emulation.writer: the rig layer may not import the emulator" \
        in problems[4]
    assert "lazy import of bracketry_emulator.benchmark.slam: floor 3 may not import floor 4" in problems[1]
    assert "import of bracketry_emulator.metrics.evaluate: bracketry_emulator.vo may not import its neighbour" \
        in problems[2]
    # a module of no layer is reported
    assert upward_imports({"elsewhere": ("", False)}, table={"bracketry_rig": RIG}) == [
        "elsewhere: in no layer (add it to the layer table)"]


def test_the_tree_with_an_upward_import_fails() -> None:
    """The real tree's sources with one bad lazy import added to a copy of one module fail, naming it."""
    modules = _tree_modules()
    source, init = modules["bracketry_base.recording.reader"]
    bad = "\n\ndef _bad():\n    from bracketry_rig.daemon import rig\n"
    modules["bracketry_base.recording.reader"] = (source + bad, init)
    problems = upward_imports(modules)
    assert len(problems) == 1 and problems[0].startswith("bracketry_base.recording.reader:"), problems
    assert "lazy import of bracketry_rig.daemon.rig: the base layer may not import the rig layer" in problems[0]


def test_no_import_cycles_between_files() -> None:
    """No file imports another that imports it back, around any loop, lazy imports included."""
    assert import_cycles(_tree_modules()) == []


def test_import_cycles_are_found() -> None:
    """On a synthetic module set: a cycle hidden behind a lazy import, a longer loop through a relative and a
    ``from package import module`` import, and no cycle from a ``TYPE_CHECKING`` import or a one-way chain."""
    modules = {
        "bracketry_emulator": ("", True),
        "bracketry_emulator.synth": ("", True),
        "bracketry_emulator.synth.world": ("from bracketry_emulator.synth.scenario import Scenario\n", False),
        "bracketry_emulator.synth.scenario": (  # back to world, lazily
            "def f():\n    from bracketry_emulator.synth.world import World\n", False),
        "bracketry_emulator.slam": ("", True),
        "bracketry_emulator.slam.launcher": ("def g():\n    import bracketry_emulator.slam.child\n", False),
        "bracketry_emulator.slam.child": ("from .orbslam3 import map_states\n", False),
        "bracketry_emulator.slam.orbslam3": (  # a loop of three, through ``from package import module``
            "def h():\n    from bracketry_emulator.slam import launcher\n", False),
        "bracketry_emulator.vo": ("", True),
        "bracketry_emulator.vo.a": ("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                                    "    from bracketry_emulator.vo.b import B\n", False),
        "bracketry_emulator.vo.b": ("from bracketry_emulator.vo.a import A\nfrom bracketry_emulator.vo.c import C\n",
                                    False),
        "bracketry_emulator.vo.c": ("", False),
    }
    assert import_cycles(modules) == [
        ["bracketry_emulator.slam.child", "bracketry_emulator.slam.launcher", "bracketry_emulator.slam.orbslam3"],
        ["bracketry_emulator.synth.scenario", "bracketry_emulator.synth.world"],
    ]


def test_benchmark_scripts_are_covered() -> None:
    """The benchmark scripts are read (their imports checked, cycles included) and no package imports them."""
    modules = _tree_modules()
    assert {"benchmarks.bench_ae", "benchmarks.bench_slam_child"} <= set(modules)
    assert upward_imports({**modules, "bracketry_base.errors": ("import benchmarks.bench_ae\n", False)}) == [
        "bracketry_base.errors:1: import of benchmarks.bench_ae: the base layer may not import the benchmarks layer"]
