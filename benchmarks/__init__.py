"""Performance measurements (issue 7). Each module ``benchmarks/<name>.py`` exposes ``run(quick=False) -> dict``;
``python -m benchmarks`` runs them all and writes ``benchmarks/results.json`` and a Markdown table."""
