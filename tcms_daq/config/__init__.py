"""Configuration: pydantic models and TOML loaders (bench, reducer catalogue, test profiles).

Invalid configuration raises :class:`tcms_daq.errors.ConfigError` with one line naming file, key and problem.
"""

from tcms_daq.config.loader import (
    apply_overrides,
    default_bench_config_path,
    default_reducer_catalogue_path,
    format_validation_error,
    get_reducer,
    load_bench_config,
    load_chain_uncertainty,
    load_reducer_catalogue,
    load_reducers_for,
    load_test_profile,
    packaged_config_dir,
    read_toml,
    resolve_config_path,
)
from tcms_daq.config.models import (
    BenchConfig,
    BenchSection,
    ChainUncertainty,
    InstrumentConfig,
    InstrumentsConfig,
    ReducerSimSpec,
    ReducerSpec,
    SimConfig,
    TestProfile,
    hd_twist_arcsec,
)

__all__ = [
    "apply_overrides",
    "BenchConfig",
    "BenchSection",
    "ChainUncertainty",
    "InstrumentConfig",
    "InstrumentsConfig",
    "ReducerSimSpec",
    "ReducerSpec",
    "SimConfig",
    "TestProfile",
    "default_bench_config_path",
    "default_reducer_catalogue_path",
    "format_validation_error",
    "get_reducer",
    "hd_twist_arcsec",
    "load_bench_config",
    "load_chain_uncertainty",
    "load_reducer_catalogue",
    "load_reducers_for",
    "load_test_profile",
    "packaged_config_dir",
    "read_toml",
    "resolve_config_path",
]
