"""docs/architecture.md is true to the code: its layer table is the import rule (every part in exactly one row,
no import pointing up a row), and its list of the core modules that read or write files is the list the source
gives."""

from __future__ import annotations

import ast
import importlib.util
import re
from pathlib import Path

# the import walker of test_imports.py (tests are not a package: loaded by path)
_spec = importlib.util.spec_from_file_location("architecture_imports", Path(__file__).with_name("test_imports.py"))
assert _spec is not None and _spec.loader is not None
_walker = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_walker)
CORE, ROOT, _edges, _in, _part, _sources = (_walker.CORE, _walker.ROOT, _walker._edges, _walker._in, _walker._part,
                                            _walker._sources)

DOC = ROOT / "docs" / "architecture.md"
FILE_IO_LINE = "Core modules that read or write files:"
# what touches a file: pathlib's read/write, open(), and the config loader's read_toml
FILE_CALLS = {"read_text", "write_text", "read_bytes", "write_bytes", "open", "read_toml"}


def layer_table(text: str) -> list[tuple[str, list[str]]]:
    """(layer, packages) of each row of the table under '## Layers', top row first."""
    section = text.split("## Layers", 1)[1].split("\n## ", 1)[0]
    rows = []
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 3 and cells[0] not in ("layer", "") and not set(cells[0]) <= {"-"}:
            rows.append((cells[0], re.findall(r"`(tcms_daq[\w.]*)`", cells[1])))
    return rows


def upward_imports(rows: list[tuple[str, list[str]]], edges: dict[tuple[str, str], list[str]]) -> list[str]:
    rank = {pkg: i for i, (_, pkgs) in enumerate(rows) for pkg in pkgs}
    bad = []
    for (a, b), wheres in sorted(edges.items()):
        if b == "tcms_daq" or b.startswith("tcms_daq.__"):  # the package root (its version)
            continue
        if rank.get(b, -1) < rank.get(a, -1):
            bad.append(f"{a} ({rows[rank[a]][0]}) -> {b} ({rows[rank[b]][0]}): {wheres[0]}")
    return bad


def test_every_part_is_in_exactly_one_layer():
    rows = layer_table(DOC.read_text(encoding="utf-8"))
    listed = [pkg for _, pkgs in rows for pkg in pkgs]
    parts = {_part(module) for _, module in _sources()} - {"tcms_daq"}
    assert len(listed) == len(set(listed)), "a package is in two rows"
    assert set(listed) == parts, f"not in the table: {sorted(parts - set(listed))}; not a part: " \
                                 f"{sorted(set(listed) - parts)}"


def test_no_import_points_up_the_table():
    rows = layer_table(DOC.read_text(encoding="utf-8"))
    bad = upward_imports(rows, _edges())
    assert not bad, "imports against docs/architecture.md's layers:\n" + "\n".join(bad)


def test_the_table_check_can_fail():
    rows = layer_table("## Layers\n| layer | packages | may |\n|---|---|---|\n| top | `tcms_daq.cli` | x |\n"
                       "| bottom | `tcms_daq.units` | y |\n## Next\n")
    assert rows == [("top", ["tcms_daq.cli"]), ("bottom", ["tcms_daq.units"])]
    assert upward_imports(rows, {("tcms_daq.units", "tcms_daq.cli"): ["units.py:1 -> tcms_daq.cli"]}) == [
        "tcms_daq.units (bottom) -> tcms_daq.cli (top): units.py:1 -> tcms_daq.cli"]


def _touches_files(path: Path) -> bool:
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Call):
            func = node.func
            name = func.attr if isinstance(func, ast.Attribute) else func.id if isinstance(func, ast.Name) else ""
            if name in FILE_CALLS:
                return True
    return False


def test_the_core_modules_that_touch_files_are_the_ones_the_doc_names():
    line = next(x for x in DOC.read_text(encoding="utf-8").splitlines() if x.startswith(FILE_IO_LINE))
    named = set(re.findall(r"`([\w/]+\.py)`", line))
    found = {path.relative_to(ROOT).as_posix() for path, module in _sources() if _in(module, CORE)
             and _touches_files(path)}
    assert named == found, f"named but not touching files: {sorted(named - found)}; touching files but not " \
                           f"named: {sorted(found - named)}"
