#!/usr/bin/env python3
"""Rewrite the drivers' option tables in docs/hardware.md from their options models (drivers/options.py).

Usage: .venv/bin/python scripts/hardware_options.py [docs/hardware.md]
"""

import sys
from pathlib import Path

from tcms_daq.config.drivers import fill_options_tables

path = Path(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).resolve().parents[1] / "docs" / "hardware.md")
text = path.read_text(encoding="utf-8")
filled = fill_options_tables(text)
if filled != text:
    path.write_text(filled, encoding="utf-8")
print(f"{path}: {'updated' if filled != text else 'up to date'}")
