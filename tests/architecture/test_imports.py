"""The import structure, read from the source (imports inside functions included).

* No cycle among the parts: the tcms_daq subpackages, ``drivers`` and ``sim`` (installed as ``tcms_daq.drivers`` and
  ``tcms_daq.sim``: the folders beside ``tcms_daq/`` are named by the package they are installed as).
* Drivers know nothing of the simulator.
* The pure core (units, errors, samples, crossval, analysis, compensation, discrepancy, procedure, transmission,
  uncertainty, and the
  protocol definitions drivers and simulators share) imports nothing of the shell (drivers, sim, acquisition, store, service, cli, config files and the environment) nor the I/O libraries,
  and never reads the environment.
"""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
# source folder -> the package it is installed as (pyproject.toml [tool.setuptools] package-dir)
PACKAGES = {"tcms_daq": "tcms_daq", "drivers": "tcms_daq.drivers", "sim": "tcms_daq.sim"}
CORE = {"tcms_daq.units", "tcms_daq.errors", "tcms_daq.samples", "tcms_daq.crossval", "tcms_daq.analysis",
        "tcms_daq.compensation", "tcms_daq.discrepancy", "tcms_daq.procedure", "tcms_daq.protocols",
        "tcms_daq.runstate", "tcms_daq.transmission", "tcms_daq.uncertainty", "tcms_daq.identity", "tcms_daq.spc"}
SHELL = {"tcms_daq.drivers", "tcms_daq.sim", "tcms_daq.acquisition", "tcms_daq.store", "tcms_daq.service", "tcms_daq.cli",
         "tcms_daq.settings"}
IO_LIBRARIES = {"fastapi", "starlette", "uvicorn", "serial", "pymodbus", "can", "canopen", "psycopg", "asyncua",
                "sqlite3", "socket"}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join([PACKAGES[parts[0]], *parts[1:]])


def _part(module: str) -> str:
    """The part a module belongs to: ``tcms_daq.<sub>`` (``tcms_daq.drivers`` and ``tcms_daq.sim`` among them)."""
    pieces = module.split(".")
    if pieces[0] == "tcms_daq" and len(pieces) > 1:
        return ".".join(pieces[:2])
    return pieces[0]


def _imports(path: Path, module: str) -> list[tuple[str, int]]:
    """Every imported module name (absolute, relative ones resolved) with its line number."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: list[tuple[str, int]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.extend((alias.name, node.lineno) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            found.append((target, node.lineno))
            found.extend((f"{target}.{alias.name}", node.lineno) for alias in node.names)
    return found


def _sources() -> list[tuple[Path, str]]:
    return [(p, _module_name(p)) for pkg in PACKAGES for p in sorted((ROOT / pkg).rglob("*.py"))]


def _internal(name: str) -> bool:
    return name.split(".")[0] == "tcms_daq"


def _edges() -> dict[tuple[str, str], list[str]]:
    """part -> part import edges, each with where it happens (file:line -> module)."""
    edges: dict[tuple[str, str], list[str]] = defaultdict(list)
    for path, module in _sources():
        for target, line in _imports(path, module):
            if not _internal(target):
                continue
            a, b = _part(module), _part(target)
            if a != b and not (b == "tcms_daq" and target.split(".")[-1] in ("__version__",)):
                edges[(a, b)].append(f"{path.relative_to(ROOT)}:{line} -> {target}")
    return edges


def _in(module_or_part: str, group: set[str]) -> bool:
    return any(module_or_part == g or module_or_part.startswith(g + ".") for g in group)


def test_no_cycle_among_parts():
    edges = _edges()
    graph: dict[str, set[str]] = defaultdict(set)
    for a, b in edges:
        if b != "tcms_daq":  # the package root (version, __init__) is not a part
            graph[a].add(b)
    cycles: list[list[str]] = []
    state: dict[str, int] = {}

    def visit(node: str, stack: list[str]) -> None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                cycles.append(stack[stack.index(nxt):] + [nxt])
            elif nxt not in state:
                visit(nxt, stack)
        stack.pop()
        state[node] = 2

    for node in sorted(list(graph)):
        if node not in state:
            visit(node, [])
    detail = []
    for cycle in cycles:
        for a, b in zip(cycle, cycle[1:], strict=False):
            detail.append(f"{a} -> {b}: {edges[(a, b)][0]}")
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles) + "\n" + "\n".join(detail)



def test_drivers_never_import_the_simulator():
    bad = [where for (a, b), wheres in _edges().items() if a == "tcms_daq.drivers" and b == "tcms_daq.sim" for where in wheres]
    assert not bad, "\n".join(bad)


def test_core_imports_nothing_of_the_shell():
    bad: list[str] = []
    for path, module in _sources():
        if not _in(module, CORE):
            continue
        source = path.read_text(encoding="utf-8")
        for target, line in _imports(path, module):
            top = target.split(".")[0]
            if (_internal(target) and _in(target, SHELL)) or top in IO_LIBRARIES:
                bad.append(f"{path.relative_to(ROOT)}:{line} imports {target}")
        if "os.environ" in source or "getenv(" in source:
            bad.append(f"{path.relative_to(ROOT)} reads the environment")
    assert not bad, "the core reaches into the shell:\n" + "\n".join(sorted(set(bad)))


def test_the_walker_sees_function_local_and_relative_imports(tmp_path):
    """The checks above can fail: a function-local relative import is found and resolved."""
    pkg = tmp_path / "tcms_daq" / "analysis"
    pkg.mkdir(parents=True)
    src = pkg / "x.py"
    src.write_text("def f():\n    from ..service import app\n    import tcms_daq.sim.bench\n", encoding="utf-8")
    found = {name for name, _ in _imports(src, "tcms_daq.analysis.x")}
    assert {"tcms_daq.service", "tcms_daq.service.app", "tcms_daq.sim.bench"} <= found


def test_nothing_imports_the_source_folders_by_their_own_names():
    """``drivers``, ``sim`` and ``benchmarks`` are not installed as top-level packages: an import of one by its folder's
    name works in the source tree (the working directory is on the path) and fails in the wheel. Benchmarks and tests,
    which are not installed, may import ``benchmarks``."""
    bad: list[str] = []
    for folder in (*PACKAGES, "tests", "benchmarks", "scripts"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            module = _module_name(path) if folder in PACKAGES else path.stem
            forbidden = {"drivers", "sim"} | ({"benchmarks"} if folder in PACKAGES else set())
            bad += [f"{path.relative_to(ROOT)}:{line} -> {target}"
                    for target, line in _imports(path, module) if target.split(".")[0] in forbidden]
    assert not bad, "\n".join(bad)
