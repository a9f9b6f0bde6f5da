"""One function builds a plan from a request: ``tcms_daq.procedure.plan.plan_from_request``. Outside
``procedure/`` nothing assembles a profile or a plan, or checks a test's bounds, by itself; the CLI and the service
call that function (grep level, over the installed packages' sources)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SOURCES = ("tcms_daq", "drivers", "sim")
# the steps of request -> plan that only tcms_daq/procedure/ may take
BUILDERS = re.compile(r"\b(build_plan|build_profile|check_test_bounds|continuous_profile|stepped_profile|"
                      r"load_test_profile|TestProfile)\s*\(")
CALLERS = ("tcms_daq/cli/run.py", "tcms_daq/service/runner.py")


def _code_lines(path: Path) -> list[tuple[int, str]]:
    """(line number, line) of the source without comments and the ``def``/``class`` lines that define names."""
    out = []
    for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        code = line.split("#", 1)[0]
        if re.match(r"\s*(def|class)\s", code):
            continue
        out.append((i, code))
    return out


def _offenders(root: Path) -> list[str]:
    bad = []
    for folder in SOURCES:
        for path in sorted((root / folder).rglob("*.py")):
            rel = path.relative_to(root).as_posix()
            if rel.startswith("tcms_daq/procedure/"):
                continue
            bad.extend(f"{rel}:{i}: {line.strip()}" for i, line in _code_lines(path) if BUILDERS.search(line))
    return bad


def test_only_procedure_builds_profiles_and_plans():
    bad = _offenders(ROOT)
    assert not bad, "a plan is built outside plan_from_request:\n" + "\n".join(bad)


def test_exactly_one_function_takes_a_request_to_a_plan():
    defs = [f"{p.relative_to(ROOT)}" for folder in SOURCES for p in (ROOT / folder).rglob("*.py")
            if re.search(r"^def plan_from_request\(", p.read_text(encoding="utf-8"), re.M)]
    assert defs == ["tcms_daq/procedure/plan.py"]
    for caller in CALLERS:
        assert "plan_from_request(" in (ROOT / caller).read_text(encoding="utf-8"), caller


def test_the_check_finds_a_plan_built_elsewhere(tmp_path):
    """The grep can fail: a profile built in the shell is reported."""
    (tmp_path / "tcms_daq" / "service").mkdir(parents=True)
    (tmp_path / "tcms_daq" / "service" / "x.py").write_text(
        "def f(t, r):\n    # build_profile(t) in a comment is fine\n    return build_profile(t, r)\n", encoding="utf-8")
    assert _offenders(tmp_path) == ["tcms_daq/service/x.py:3: return build_profile(t, r)"]
