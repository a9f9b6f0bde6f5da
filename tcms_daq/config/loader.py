"""TOML loaders for the configuration files. Every problem becomes a one-line ConfigError naming file, key, problem."""

from __future__ import annotations

import os
import tomllib
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel, ValidationError

from tcms_daq.config.models import BenchConfig, ReducerSpec, TestProfile
from tcms_daq.errors import ConfigError

M = TypeVar("M", bound=BaseModel)

#: Environment variable that points at a config directory (default: ``config/`` of the source tree).
CONFIG_DIR_ENV = "TCMS_CONFIG_DIR"


def default_config_dir() -> Path:
    env = os.environ.get(CONFIG_DIR_ENV)
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[2] / "config"


def default_bench_config_path() -> Path:
    return default_config_dir() / "bench-sim.toml"


def default_reducer_catalogue_path() -> Path:
    return default_config_dir() / "reducers.toml"


def read_toml(path: str | Path) -> dict[str, Any]:
    """Parse a TOML file; a missing file or a syntax error is a ConfigError naming the file."""
    path = Path(path)
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: invalid TOML: {exc}") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read ({exc.strerror or exc})") from None


def _key_path(prefix: str, loc: tuple[Any, ...]) -> str:
    parts = [prefix] if prefix else []
    parts += [str(p) for p in loc]
    return ".".join(parts) or "(top level)"


def _problem(err: dict[str, Any]) -> str:
    kind = err.get("type", "")
    msg = err.get("msg", "invalid value")
    if kind == "missing":
        return "missing key"
    if kind == "extra_forbidden":
        return "unknown key"
    if msg.startswith("Value error, "):
        msg = msg[len("Value error, "):]
    if "input" in err and kind not in ("model_type", "dict_type"):
        return f"{msg} (got {err['input']!r})"
    return msg


def format_validation_error(path: str | Path, exc: ValidationError, prefix: str = "") -> str:
    """One line: ``file: key: problem`` for the first error (and how many more there are)."""
    errors = exc.errors()
    first = errors[0]
    loc = tuple(p for p in first.get("loc", ()) if p != "__root__")
    line = f"{path}: {_key_path(prefix, loc)}: {_problem(first)}"
    if len(errors) > 1:
        line += f" (and {len(errors) - 1} more problem{'s' if len(errors) > 2 else ''})"
    return line


def validate(model: type[M], data: Any, path: str | Path, prefix: str = "") -> M:
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(format_validation_error(path, exc, prefix)) from None


def load_reducer_catalogue(path: str | Path | None = None) -> dict[str, ReducerSpec]:
    """Read the reducer catalogue (``config/reducers.toml`` by default): ``[reducers.<NAME>]`` tables."""
    path = Path(path) if path is not None else default_reducer_catalogue_path()
    data = read_toml(path)
    table = data.get("reducers")
    if not isinstance(table, dict) or not table:
        raise ConfigError(f"{path}: reducers: missing key (expected [reducers.<NAME>] tables)")
    out: dict[str, ReducerSpec] = {}
    for name, entry in table.items():
        if not isinstance(entry, dict):
            raise ConfigError(f"{path}: reducers.{name}: expected a table, got {type(entry).__name__}")
        out[name] = validate(ReducerSpec, {"name": name, **entry}, path, prefix=f"reducers.{name}")
    return out


def get_reducer(catalogue: dict[str, ReducerSpec], name: str, path: str | Path | None = None) -> ReducerSpec:
    """Look a reducer up by name (case-insensitive); an unknown name is a ConfigError listing the known ones."""
    if name in catalogue:
        return catalogue[name]
    folded = {k.casefold(): v for k, v in catalogue.items()}
    if name.casefold() in folded:
        return folded[name.casefold()]
    where = f"{path}: " if path is not None else ""
    raise ConfigError(f"{where}unknown reducer {name!r} (known: {', '.join(sorted(catalogue))})")


def load_bench_config(path: str | Path | None = None) -> BenchConfig:
    """Read a bench configuration (``config/bench-sim.toml`` by default)."""
    path = Path(path) if path is not None else default_bench_config_path()
    data = read_toml(path)
    cfg = validate(BenchConfig, data, path)
    cfg.source_path = str(path)
    return cfg


def load_reducers_for(cfg: BenchConfig) -> dict[str, ReducerSpec]:
    """The catalogue a bench config names (``[bench] reducers``, relative to the file; default reducers.toml, and
    the shipped catalogue when no reducers.toml lies next to the file)."""
    candidate = Path(cfg.resolve(cfg.bench.reducers))
    if not candidate.exists() and cfg.bench.reducers == "reducers.toml":
        return load_reducer_catalogue()  # a copied bench file without its catalogue: the shipped one
    return load_reducer_catalogue(candidate)


def load_test_profile(data: dict[str, Any], source: str = "<profile>") -> TestProfile:
    """Validate a test-profile mapping (from an API request or a [procedure] table)."""
    return validate(TestProfile, data, source)
