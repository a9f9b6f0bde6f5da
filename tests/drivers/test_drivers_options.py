"""Each driver's options are one pydantic model: the bench config validates an instrument's table against it when the
file is read, the driver is built from it, and docs/hardware.md's option tables are written from it."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError
from tcms_daq.drivers.aed import AED
from tcms_daq.drivers.cia402_canopen import CiA402Canopen
from tcms_daq.drivers.cia402_modbus import CiA402Modbus
from tcms_daq.drivers.cia402_velocity import CiA402VelocityCanopen, CiA402VelocityModbus
from tcms_daq.drivers.counter import Counter2Axis
from tcms_daq.drivers.nd287 import ND287, ND287Coupled
from tcms_daq.drivers.options import CiA402CanopenOptions, CiA402ModbusOptions, ND287Options

from tcms_daq.config.drivers import OPTIONS_BLOCK, fill_options_tables, names, options_model
from tcms_daq.config.models import DriverOptions

ROOT = Path(__file__).resolve().parents[2]
HARDWARE = {"nd287": ND287, "aed": AED, "cia402-canopen": CiA402Canopen, "cia402-modbus": CiA402Modbus,
            "cia402-velocity-canopen": CiA402VelocityCanopen, "cia402-velocity-modbus": CiA402VelocityModbus,
            "nd287-coupled": ND287Coupled, "counter-2axis": Counter2Axis}


def test_every_registered_driver_declares_an_options_model_that_forbids_unknown_keys():
    assert set(HARDWARE) | {"virtual"} <= set(names())
    for name in names():
        model = options_model(name)
        assert issubclass(model, DriverOptions) and model.model_config.get("extra") == "forbid", name
        assert "url" in model.model_fields, name
    for name, cls in HARDWARE.items():
        assert options_model(name) is cls.options_model


def test_the_models_check_what_the_constructors_used_to():
    with pytest.raises(ValidationError, match="node ids must differ"):
        CiA402CanopenOptions(url="virtual://x", node_id=5, master_node_id=5)
    with pytest.raises(ValidationError, match="at least 3 master heartbeat periods"):
        CiA402CanopenOptions(url="virtual://x", master_heartbeat_ms=100, drive_consumer_timeout_ms=250)
    with pytest.raises(ValidationError, match="counts_per_rev"):
        CiA402ModbusOptions(url="tcp://127.0.0.1:1", counts_per_rev=0)
    with pytest.raises(ValidationError, match="torque_slope_nm_per_s"):
        CiA402ModbusOptions(url="tcp://127.0.0.1:1", torque_slope_nm_per_s=float("nan"))
    with pytest.raises(ValidationError, match="readings_per_read"):
        ND287Options(url="socket://x:1", readings_per_read=0)
    assert CiA402CanopenOptions(url="virtual://x", master_heartbeat_ms=50).consumer_timeout_ms == 500


def test_a_serial_driver_is_built_from_its_options():
    options = ND287Options(url="socket://unused:1", readings_per_read=3, name="angle")
    nd = ND287(options, clock=lambda: 0.0)  # not connected: nothing is opened
    assert nd.readings_per_read == 3 and nd.name == "angle" and nd.link.url == "socket://unused:1"


def test_hardware_md_option_tables_are_the_models():
    text = (ROOT / "docs" / "hardware.md").read_text(encoding="utf-8")
    documented = {m.group("driver") for m in OPTIONS_BLOCK.finditer(text)}
    assert documented == set(HARDWARE), f"docs/hardware.md has option tables for {sorted(documented)}"
    assert fill_options_tables(text) == text, (
        "docs/hardware.md's option tables differ from the drivers' options models: run "
        ".venv/bin/python scripts/hardware_options.py")


def test_hardware_md_examples_are_valid_instrument_tables():
    """Every ``[instruments.*]`` example in docs/hardware.md passes its driver's options model as written."""
    import re
    import tomllib

    from tcms_daq.config.models import InstrumentsConfig

    text = (ROOT / "docs" / "hardware.md").read_text(encoding="utf-8")
    examples = [tomllib.loads(block) for block in re.findall(r"```toml\n(.*?)```", text, re.S)]
    tables = [ex["instruments"] for ex in examples if "instruments" in ex]
    assert {kind for t in tables for kind in t} == {"angle", "torque", "loader", "input_drive", "input_torque",
                                                    "input_angle"}
    for table in tables:
        InstrumentsConfig.model_validate(table)
