"""The sign-in lockout: failed sign-ins counted per user name and per client address within a window; at the
admin's threshold (:class:`~tcms_daq.service.admin_settings.AdminSettings`) further attempts get 429 with
``Retry-After`` until the oldest counted failure leaves the window. Kept in the service's memory (a restart
forgets it; the audit trail keeps every failure). Behind a reverse proxy every client has the proxy's address,
so the per-address threshold then counts the whole plant.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict, deque

from tcms_daq.service.admin_settings import AdminSettings

#: at most this many names and addresses are remembered (the least recently failed are forgotten first), so
#: sign-ins with made-up names cannot fill the memory
MAX_KEYS = 10_000
#: failures kept per key: the largest threshold AdminSettings allows
MAX_FAILURES_KEPT = 1000


class SignInLimiter:
    """Failures per key (``user:<name>``, ``address:<host>``), with times in seconds of any monotonic clock."""

    def __init__(self) -> None:
        self._failures: OrderedDict[str, deque[float]] = OrderedDict()
        self._lock = threading.Lock()

    @staticmethod
    def _keys(name: str, address: str) -> tuple[tuple[str, str], tuple[str, str]]:
        return (f"user:{name.casefold()}", "user"), (f"address:{address}", "address")

    def retry_after_s(self, name: str, address: str, now: float, policy: AdminSettings) -> int | None:
        """Whole seconds until a sign-in of ``name`` from ``address`` may be tried again; None: it may now."""
        waits = []
        with self._lock:
            for key, kind in self._keys(name, address):
                times = self._failures.get(key)
                if times is None:
                    continue
                while times and times[0] <= now - policy.lockout_s:
                    times.popleft()
                threshold = (policy.lockout_failures_per_user if kind == "user"
                             else policy.lockout_failures_per_address)
                if len(times) >= threshold:
                    waits.append(times[-threshold] + policy.lockout_s - now)
        return max(1, math.ceil(max(waits))) if waits else None

    def failed(self, name: str, address: str, now: float) -> None:
        """Count one failed sign-in of ``name`` from ``address``."""
        with self._lock:
            for key, _kind in self._keys(name, address):
                times = self._failures.pop(key, None) or deque(maxlen=MAX_FAILURES_KEPT)
                times.append(now)
                self._failures[key] = times  # most recently failed last
            while len(self._failures) > MAX_KEYS:
                self._failures.popitem(last=False)

    def succeeded(self, name: str) -> None:
        """A correct sign-in clears its user's failures (not its address's)."""
        with self._lock:
            self._failures.pop(self._keys(name, "")[0][0], None)
