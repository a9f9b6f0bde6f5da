"""Typed configuration end to end: the composition of a bench (config -> drivers, physics, compensator, interlocks)
takes the validated models, and no signature on that path says ``Any`` (grep level, over the AST)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
# file -> the classes and functions of the composition in it (None: every top-level function and class)
COMPOSITION: dict[str, set[str] | None] = {
    "tcms_daq/acquisition/bench.py": {"Bench", "compose_bench", "bench_from_file",
                                      "read_bench_config", "load_compensator"},
    "drivers/registry.py": None,
    "sim/virtual.py": {"VirtualDriver", "VirtualContext", "BenchPhysics", "PositioningPhysics"},
    "sim/bench.py": {"SimulatedBench.__init__", "SimulatedBench.from_config", "_as_bench_config"},
    "tcms_daq/service/runner.py": {"BenchRunner.__init__", "BenchRunner.from_config"},
}
# free-form by design: what a bench shows of itself (driver names and options, for people and the status API)
FREE_FORM = {"tcms_daq/acquisition/bench.py:Bench.description"}


def _annotations(node: ast.AST) -> list[tuple[str, ast.expr]]:
    """(name, annotation) of a function's parameters and return, or of a class body's annotated fields."""
    if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
        a = node.args
        params = [*a.posonlyargs, *a.args, *a.kwonlyargs, *([a.vararg] if a.vararg else []),
                  *([a.kwarg] if a.kwarg else [])]
        out = [(f"{node.name}({p.arg})", p.annotation) for p in params if p.annotation is not None]
        return out + ([(f"{node.name}() ->", node.returns)] if node.returns is not None else [])
    return []


def _typed_with_any(path: str, wanted: set[str] | None, source: str | None = None) -> list[str]:
    tree = ast.parse(source if source is not None else (ROOT / path).read_text(encoding="utf-8"))
    found: list[str] = []

    def check(qualname: str, name: str, annotation: ast.expr) -> None:
        text = ast.unparse(annotation)
        if re.search(r"\bAny\b", text):
            found.append(f"{path}: {qualname}: {name}: {text}")

    for node in tree.body:
        if isinstance(node, ast.FunctionDef) and (wanted is None or node.name in wanted):
            for name, ann in _annotations(node):
                check(node.name, name, ann)
        elif isinstance(node, ast.ClassDef):
            whole = wanted is None or node.name in wanted
            for item in node.body:
                qual = f"{node.name}.{getattr(item, 'name', '')}"
                if isinstance(item, ast.FunctionDef) and (whole or qual in (wanted or ())):
                    for name, ann in _annotations(item):
                        check(qual, name, ann)
                elif isinstance(item, ast.AnnAssign) and whole and isinstance(item.target, ast.Name):
                    field = f"{node.name}.{item.target.id}"
                    if f"{path}:{field}" not in FREE_FORM:
                        check(field, "field", item.annotation)
    return found


def test_no_any_in_the_composition_signatures():
    bad = [line for path, wanted in COMPOSITION.items() for line in _typed_with_any(path, wanted)]
    assert not bad, "the composition takes untyped values:\n" + "\n".join(bad)


def test_compose_bench_takes_the_validated_config():
    tree = ast.parse((ROOT / "tcms_daq/acquisition/bench.py").read_text(encoding="utf-8"))
    compose = next(n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == "compose_bench")
    assert ast.unparse(compose.args.args[0].annotation) == "BenchConfig"
    source = ast.unparse(compose)
    assert "_section(" not in source and "_as_dict(" not in source and "model_validate" not in source


def test_the_check_finds_any(tmp_path):
    """The check can fail: an ``Any`` in a parameter, a return or a field is reported."""
    source = ("from typing import Any\n"
              "def compose(config: Any) -> int: ...\n"
              "class Ctx:\n    options: dict[str, Any]\n    def f(self) -> 'Any': ...\n")
    found = _typed_with_any("x.py", None, source)
    assert found == ["x.py: compose: compose(config): Any", "x.py: Ctx.options: field: dict[str, Any]",
                     "x.py: Ctx.f: f() ->: 'Any'"]
