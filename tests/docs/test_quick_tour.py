"""The README's quick tour runs as written, top to bottom, in an empty directory outside the source tree, with this
interpreter's ``tcms`` and ``python`` first on PATH (scripts/quick_tour.py; the wheel smoke runs the same tour
with the wheel installed in a fresh venv). CI runs the tour once, from the wheel: ``.ci/run`` sets
``TCMS_QUICK_TOUR=wheel-smoke`` for pytest, and the wheel smoke fails the job when a line of the tour fails."""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("quick_tour", REPO / "scripts" / "quick_tour.py")
assert _spec and _spec.loader
quick_tour = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(quick_tour)


def test_the_tour_says_tcms_not_a_path_into_the_source_tree():
    commands = quick_tour.tour_commands()
    assert any("tcms examples" in c for c in commands) and any(c.endswith("&") for c in commands)
    assert not [c for c in commands if ".venv/" in c], "the tour runs in an empty directory: no .venv/bin/ paths"
    background = next(c for c in commands if c.endswith("&"))
    assert "--free-ports" in background, "the simulators of the tour take free ports, not well-known ones"


@pytest.mark.slow
@pytest.mark.skipif(os.environ.get("TCMS_QUICK_TOUR") == "wheel-smoke",
                    reason="this job runs the tour from the installed wheel (.ci/run: scripts/wheel_smoke.py)")
@pytest.mark.timeout(1800)  # some twenty commands, each a few seconds to a minute: far beyond the suite's 300 s
def test_quick_tour_runs_as_written(tmp_path):
    quick_tour.run_tour(Path(sys.executable).parent, tmp_path)
    assert (tmp_path / "report" / "report.html").is_file() and (tmp_path / "comp.toml").is_file()
