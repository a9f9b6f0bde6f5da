"""``python -m tcms_daq.discrepancy.trials``: the hidden-effect trials of the discrepancy workflow.

A command-line entry, not part of the pure core: the trials drive the simulated bench (``sim.trials``, shipped
in the same wheel), which the core modules never import. Naming accuracy, false names, parameter errors and the
out-of-catalogue honesty rate over seeds; ``--help`` for the options.
"""

from __future__ import annotations

import sys


def main(argv: list[str] | None = None) -> int:
    from sim.trials import main as run_trials  # the simulator is reached from this entry only

    return run_trials(argv, prog="python -m tcms_daq.discrepancy.trials")


if __name__ == "__main__":
    sys.exit(main())
