"""What ``tcms serve`` configures for the service (the app's settings; the environment's are
:mod:`tcms_daq.settings`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


@dataclass
class ServiceSettings:
    """What ``tcms serve`` configures. ``sim_speed``: simulated seconds per real second."""

    data_dir: Path
    config_path: Path | None = None
    store_url: str | None = None  # postgresql://… (None: the SQLite file in data_dir)
    opcua_port: int | None = None  # OPC UA server on opc.tcp://<[opcua] host>:<port> (None: off; 0: any free port)
    opcua: Any = None  # the [opcua] section (tcms_daq.config.models.OpcUaSection; None: the bench config's)
    sim_speed: float = 1.0
    api_token: str | None = None
    frame_rate_hz: float = 25.0
    live_queue_frames: int = 50
    live_stall_timeout_s: float = 5.0
    live_max_samples_per_frame: int | None = 4000  # min/max decimation above this (live view only)
    recorder_flush_s: float = 0.2
    max_body_bytes: int = 1 << 20  # every request body (413 above it); a compensation TOML is a few kB
    # browsers: WebSockets accept these Origins (besides the service's own, same host:port); None = only its own
    allowed_origins: tuple[str, ...] = ()
    # Host header check against DNS rebinding; None = any host (a service bound to all interfaces)
    allowed_hosts: tuple[str, ...] | None = ("127.0.0.1", "localhost", "::1", "[::1]")
    # reads (/api/…, /ws/…, /metrics) need the token too (``tcms serve`` turns this on beyond loopback)
    read_token_required: bool = False
    extra: dict[str, Any] = field(default_factory=dict)
