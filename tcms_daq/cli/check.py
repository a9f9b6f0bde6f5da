"""``tcms check --config FILE``: is every instrument of a bench there? Nothing moves.

Connects to each configured instrument in turn (angle source, torque source, loader), reads it for
``--duration`` seconds of the bench's clock and reports what it found: the driver and its identity where the
driver states one, how many readings arrived per second, the last reading, and the loader's state (drive state,
torque actual, position, fault) — without enabling the loader or commanding anything. An instrument that does not
answer is named with the driver's one-line reason. Exit code 0 when every instrument answered, 1 when one is
down, 2 for a bad config.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

from tcms_daq.cli.options import add_bench_config_options
from tcms_daq.errors import TcmsError

UNITS = {"angle": "″", "torque": "N·m"}


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0 < value <= 60:
        raise argparse.ArgumentTypeError(f"must be > 0 and <= 60 s, got {text}")
    return value


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "check", help="connect to each instrument of a bench, read it, report; nothing moves",
        description="Connect to each configured instrument, read it and report identity, reading rate and the "
        "drive's state without moving anything; names the instrument that is down (exit code 1).")
    add_bench_config_options(p)
    p.add_argument("--duration", type=_positive, default=1.0, metavar="S",
                   help="how long to read each sensor, in the bench clock's seconds (default 1)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    p.set_defaults(func=run)


def _read_sensor(drv: Any, clock: Any, duration_s: float) -> dict[str, Any]:
    """Read a sensor for ``duration_s`` of the bench clock: reading count, rate over the stamped times, last value."""
    count, first_s, last_s, last_value = 0, None, None, None
    deadline = clock.now() + duration_s
    while clock.now() < deadline:
        batch = drv.read()
        if len(batch):
            count += len(batch)
            first_s = float(batch.time_s[0]) if first_s is None else first_s
            last_s, last_value = float(batch.time_s[-1]), float(batch.value[-1])
        clock.sleep(0.01)
    if count == 0:
        raise TcmsError(f"{drv.name}: connected, but no reading within {duration_s:g} s")
    span = (last_s - first_s) if first_s is not None and last_s is not None else 0.0
    return {"readings": count, "rate_per_s": (count - 1) / span if span > 0 and count > 1 else None,
            "last_value": last_value}


def _loader_state(drv: Any) -> dict[str, Any]:
    st = drv.status()
    return {"state": st.state, "torque_actual_nm": st.torque_actual_nm, "position_deg": st.position_deg,
            "fault": st.fault, "error_code": st.error_code,
            "can_move": callable(getattr(drv, "move_to", None)), "rated_torque_nm": drv.rated_torque_nm}


def check_bench(bench: Any, duration_s: float) -> list[dict[str, Any]]:
    """One entry per instrument: kind, driver, url, ok, and what was read, or the error that names it."""
    out = []
    for kind, drv in bench.instruments().items():
        described = dict(bench.description.get(kind, {}))
        entry: dict[str, Any] = {"kind": kind, "instrument": getattr(drv, "name", kind),
                                 "driver": described.get("driver"), "url": described.get("url")}
        try:
            drv.connect()
            identity = getattr(drv, "identity", None)
            if callable(identity):
                entry["identity"] = identity()
            entry.update(_loader_state(drv) if kind == "loader" else _read_sensor(drv, bench.clock, duration_s))
            entry["ok"] = True
        except Exception as exc:  # any failure of this instrument is its report, the others are still checked
            entry["ok"] = False
            entry["error"] = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        finally:
            try:
                drv.close()
            except Exception as exc:  # noqa: BLE001 - closing a link that never opened
                entry.setdefault("close_error", str(exc))
        out.append(entry)
    return out


def _line(e: dict[str, Any]) -> str:
    head = f"{e['kind']:<7} {e['driver'] or '?':<15} {e['url'] or '':<36}"
    if not e["ok"]:
        return f"{head} DOWN  {e['error']}"
    if e["kind"] == "loader":
        where = "" if e.get("position_deg") is None else f", position {e['position_deg']:.3f}°"
        fault = f", FAULT 0x{e['error_code']:04X}" if e.get("fault") else ""
        text = (f"{e['state']}, torque {e['torque_actual_nm']:.3g} N·m{where}{fault}, rated {e['rated_torque_nm']:g} "
                f"N·m, {'position mode' if e['can_move'] else 'no position mode'}")
    else:
        rate = "?" if e["rate_per_s"] is None else f"{e['rate_per_s']:.1f}"
        text = f"{e['readings']} readings, {rate} per s, last {e['last_value']:.6g} {UNITS[e['kind']]}"
    identity = e.get("identity")
    return f"{head} OK    {text}" + (f" ({', '.join(f'{k} {v}' for k, v in identity.items())})" if identity else "")


def run(args: argparse.Namespace) -> int:
    from tcms_daq.acquisition import compose_bench
    from tcms_daq.config import load_bench_config

    cfg = load_bench_config(args.config, args.overrides)
    config_dir = Path(cfg.source_path).parent if cfg.source_path else None
    bench = compose_bench(cfg, config_dir=config_dir)
    started = time.monotonic()
    entries = check_bench(bench, args.duration)
    down = [e for e in entries if not e["ok"]]
    if args.json:
        print(json.dumps({"bench": cfg.bench.name, "config": cfg.source_path, "ok": not down,
                          "down": [e["kind"] for e in down], "instruments": entries,
                          "check_s": time.monotonic() - started}, allow_nan=False))
    else:
        print(f"{cfg.bench.name} ({cfg.source_path}): nothing was moved or enabled")
        for e in entries:
            print(_line(e))
        print("all instruments answered" if not down else
              "down: " + ", ".join(f"{e['kind']} ({e['instrument']})" for e in down))
    return 1 if down else 0
