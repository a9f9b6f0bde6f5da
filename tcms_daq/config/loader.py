"""TOML loaders for the configuration files. Every problem becomes a one-line ConfigError naming file, key, problem."""

from __future__ import annotations

import tomllib
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel, ValidationError

from tcms_daq.config.models import BenchConfig, ChainUncertainty, ReducerSpec, TestProfile
from tcms_daq.errors import ConfigError

M = TypeVar("M", bound=BaseModel)


def packaged_config_dir() -> Path:
    """The packaged default configuration (``config/`` in the source tree, installed as ``tcms_daq.defaults``)."""
    return Path(str(resources.files("tcms_daq.defaults")))


def default_bench_config_path() -> Path:
    return packaged_config_dir() / "bench-sim.toml"


def default_reducer_catalogue_path() -> Path:
    return packaged_config_dir() / "reducers.toml"


def resolve_config_path(path: str | Path) -> Path:
    """A config file as given; a bare file name that is not in the working directory names a packaged default
    (``--config bench-loopback.toml`` works from any directory). A missing file is a ConfigError that lists the
    packaged configs."""
    given = Path(path)
    if given.exists():
        return given
    if given.parent != Path("."):
        raise ConfigError(f"{given}: no such file")
    if (packaged_config_dir() / given.name).is_file():
        return packaged_config_dir() / given.name
    names = ", ".join(sorted(p.name for p in packaged_config_dir().glob("*.toml")))
    raise ConfigError(f"{given}: no such file (packaged configs, usable by name: {names})")


def apply_overrides(data: dict[str, Any], assignments: list[str] | tuple[str, ...], source: str = "--set"
                    ) -> dict[str, Any]:
    """A copy of a parsed TOML document with ``dotted.key=VALUE`` assignments applied (VALUE in TOML syntax;
    a bare word is taken as a string): ``instruments.angle.url=socket://127.0.0.1:5001``. Tables on the way
    are created; assigning into a non-table is a ConfigError."""
    import copy

    out = copy.deepcopy(data)
    for item in assignments:
        key, sep, raw = item.partition("=")
        parts = [p.strip() for p in key.strip().split(".")]
        if not sep or not all(parts):
            raise ConfigError(f"{source} {item!r}: expected dotted.key=VALUE")
        try:
            value = tomllib.loads(f"v = {raw.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            value = raw.strip()
        node = out
        for i, part in enumerate(parts[:-1]):
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                raise ConfigError(f"{source} {item!r}: {'.'.join(parts[:i + 1])} is not a table")
            node = child
        node[parts[-1]] = value
    return out


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


def _problem(err: Mapping[str, Any]) -> str:
    kind = err.get("type", "")
    msg = err.get("msg", "invalid value")
    if kind == "missing":
        return "missing key"
    if kind == "extra_forbidden":
        return "unknown key"
    if kind == "driver_options":  # complete already (tcms_daq.config.drivers): names the driver, the key, the keys
        return str(msg)
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
    if first.get("type") == "driver_options" and loc[-1:] == ("options",):
        loc = loc[:-1]  # the options are the instrument table's own keys in the file
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
    """Read the reducer catalogue (the packaged ``reducers.toml`` by default): ``[reducers.<NAME>]`` tables."""
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


def load_bench_config(path: str | Path | None = None, overrides: list[str] | tuple[str, ...] = ()) -> BenchConfig:
    """Read a bench configuration (the packaged ``bench-sim.toml`` by default; a bare name may name another
    packaged one), with ``dotted.key=VALUE`` overrides (:func:`apply_overrides`) applied before validation."""
    path = resolve_config_path(path) if path is not None else default_bench_config_path()
    data = apply_overrides(read_toml(path), overrides)
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


def load_chain_uncertainty(path: str | Path) -> ChainUncertainty:
    """Read declared standard uncertainties (k = 1) of a measuring chain: ``[torque]``, ``[angle]``,
    ``[compensation]``, ``[reference]``, ``[temperature]`` tables (``tcms analyze --uncertainty FILE.toml``)."""
    chain = validate(ChainUncertainty, read_toml(path), path)
    chain.source = str(path)
    return chain
