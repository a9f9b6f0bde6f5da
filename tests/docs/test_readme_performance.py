"""The README's performance table is what ``python -m benchmarks --readme`` writes from benchmarks/results.json:
no figure in it is typed by hand."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from benchmarks._report import (
    PLANT_BEGIN,
    PLANT_END,
    README_BEGIN,
    README_END,
    plant_scale_table,
    readme_table,
    readme_table_in,
    replace_readme_table,
)

REPO = Path(__file__).resolve().parents[2]


def test_the_readme_table_is_generated_from_results_json():
    results = json.loads((REPO / "benchmarks" / "results.json").read_text(encoding="utf-8"))["results"]
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    assert readme_table_in(readme) == readme_table(results), (
        "README.md's performance table differs from benchmarks/results.json: run `python -m benchmarks --readme`")
    assert readme_table_in(readme, (PLANT_BEGIN, PLANT_END)) == plant_scale_table(results), (
        "README.md's plant_scale table differs from benchmarks/results.json: run `python -m benchmarks --readme`")


def test_the_table_gives_min_median_max_the_target_and_the_load():
    result = {
        "name": "evaluation", "quick": False, "measured_at": 0.0,
        "load_average_1min": {"before": 0.25, "after": 1.5, "cpus": 2},
        "metrics": {"evaluation_time_per_million_samples_s_min": 0.071,
                    "evaluation_time_per_million_samples_s_median": 0.08,
                    "evaluation_time_per_million_samples_s_max": 1.2},
        "targets": {"evaluation_time_per_million_samples_s_max": {"limit": 1.0, "met": False}},
    }
    table = readme_table([result])
    row = next(line for line in table.splitlines() if "hysteresis evaluation" in line)
    assert "0.071 / 0.08 / 1.2 s" in row and "**not met**" in row
    assert "1970-01-01 00:00 UTC, load 0.25 → 1.50 (2 CPUs)" in row
    assert "not in benchmarks/results.json" in next(line for line in table.splitlines() if "| protocols |" in line)
    quick = readme_table([{**result, "quick": True}])
    assert "quick run (a smoke test, not a measurement)" in quick


def test_rewriting_replaces_only_the_generated_part():
    readme = f"# Title\n\nbefore\n{README_BEGIN}\n| old |\n{README_END}\nafter\n"
    rewritten = replace_readme_table(readme, "| new |\n")
    assert rewritten == f"# Title\n\nbefore\n{README_BEGIN}\n| new |\n{README_END}\nafter\n"
    assert readme_table_in(rewritten) == "| new |\n"
    with pytest.raises(ValueError, match="no generated performance table"):
        replace_readme_table("# no markers\n", "| new |\n")
