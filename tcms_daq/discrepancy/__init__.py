"""Discrepancy workflow: find where simulation and measurement disagree, name the missing effect, add it to
the model and show the gap shrink (DESIGN §8). Pure numpy; entry point :func:`run_discrepancy`."""

from tcms_daq.discrepancy.catalogue import CATALOGUE, EFFECT_NAMES
from tcms_daq.discrepancy.workflow import DiscrepancyResult, run_discrepancy

__all__ = ["CATALOGUE", "EFFECT_NAMES", "DiscrepancyResult", "run_discrepancy"]
