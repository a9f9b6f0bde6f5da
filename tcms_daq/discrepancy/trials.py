"""``python -m tcms_daq.discrepancy.trials``: the hidden-effect trials of the discrepancy workflow.

A command-line entry, not part of the pure core's computation. The trials need a bench that hides effects in a
measurement; the core never imports one. It finds it as it finds user-declared effects: through an entry point,
of the group ``tcms_daq.trials`` (this distribution registers the simulated bench's trials, ``sim.trials:main``).
Naming accuracy, false names, parameter errors and the out-of-catalogue honesty rate over seeds; ``--help`` for
the options.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from importlib.metadata import entry_points

ENTRY_POINT_GROUP = "tcms_daq.trials"
PROG = "python -m tcms_daq.discrepancy.trials"


def trial_runner(name: str = "simulated-bench") -> Callable[..., int]:
    """The installed trial runner ``name`` of the group ``tcms_daq.trials`` (a ``main(argv, prog=…)``)."""
    found = {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}
    if name not in found:
        installed = ", ".join(sorted(found)) or "none"
        raise LookupError(f"no trial runner {name!r} in the entry point group {ENTRY_POINT_GROUP} "
                          f"(installed: {installed}); reinstall tcms-daq")
    runner: Callable[..., int] = found[name].load()
    return runner


def main(argv: list[str] | None = None) -> int:
    try:
        runner = trial_runner()
    except LookupError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return runner(argv, prog=PROG)


if __name__ == "__main__":
    sys.exit(main())
