"""Declared chain uncertainties in the bench config: the packaged benches declare them, bad values are one line."""

import pytest

from tcms_daq.acquisition import compose_bench
from tcms_daq.config import load_bench_config
from tcms_daq.errors import ConfigError


def test_packaged_bench_declares_its_chain_and_rule():
    cfg = load_bench_config()
    chain = cfg.chain_uncertainty()
    assert chain is not None and chain.torque.u_rel > 0 and chain.angle.u_interpolation_arcsec > 0
    assert chain.compensation.u_rel > 0 and "bench config" in chain.source
    assert cfg.bench.decision_rule == "guarded"
    compose_bench(cfg, config_dir=cfg.resolve("."))  # the declaration is not handed to the drivers


def test_nothing_declared_is_none():
    cfg = load_bench_config(overrides=["instruments.torque.uncertainty.u_rel=0", "instruments.torque.uncertainty.u_zero_nm=0",
                                       "instruments.angle.uncertainty={}", "uncertainty={}"])
    assert cfg.chain_uncertainty() is None


@pytest.mark.parametrize("override, message", [
    ("instruments.torque.uncertainty.u_rel=-0.1", "instruments.torque.uncertainty.u_rel"),
    ("instruments.angle.uncertainty.bogus=1", "instruments.angle.uncertainty.bogus: unknown key"),
    ("bench.decision_rule='lenient'", "bench.decision_rule"),
])
def test_bad_declarations_are_one_line(override, message):
    with pytest.raises(ConfigError, match=message.replace(".", r"\.")) as exc:
        load_bench_config(overrides=[override])
    assert "\n" not in str(exc.value)
