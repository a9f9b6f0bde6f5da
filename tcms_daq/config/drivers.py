"""The drivers a bench config may name, found by name in the entry-point group ``tcms_daq.drivers`` (pyproject
``[project.entry-points]``), in the style of python-can's interface registry, and each driver's options model.

Every driver class declares ``options_model``, a :class:`tcms_daq.config.models.DriverOptions` subclass: the keys
of its ``[instruments.<kind>]`` table. A bench config's instrument options are validated against it once, when the
config is read. The configuration finds a driver as a plugin (by its entry point, never by an import), so it
imports a driver's module, and the libraries that one uses, only when a bench names it.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from importlib.metadata import entry_points
from types import UnionType
from typing import Literal, get_args, get_origin

from pydantic import ValidationError
from pydantic_core import PydanticCustomError

from tcms_daq.config.models import DriverOptions
from tcms_daq.errors import ConfigError

ENTRY_POINT_GROUP = "tcms_daq.drivers"

_LOADED: dict[str, type] = {}


def names() -> list[str]:
    """The driver names available in this installation."""
    return sorted({ep.name for ep in entry_points(group=ENTRY_POINT_GROUP)})


def driver_class(name: str) -> type:
    """The class registered as ``name``; ConfigError naming the known drivers otherwise."""
    if name not in _LOADED:
        found = [ep for ep in entry_points(group=ENTRY_POINT_GROUP) if ep.name == name]
        if not found:
            raise ConfigError(f"unknown driver {name!r} (known: {', '.join(names()) or 'none'})")
        _LOADED[name] = found[0].load()
    return _LOADED[name]


def options_model(name: str) -> type[DriverOptions]:
    """The options model of the driver ``name``; ConfigError when it declares none."""
    model = getattr(driver_class(name), "options_model", None)
    if not (isinstance(model, type) and issubclass(model, DriverOptions)):
        raise ConfigError(f"driver {name!r} declares no options model (a DriverOptions subclass as the class "
                          "attribute options_model)")
    return model


def validate_driver_options(driver: str, table: Mapping[str, object]) -> DriverOptions:
    """``table`` (the instrument's keys but driver, calibration and uncertainty) validated against the options
    model of ``driver``. Errors are a ``driver_options`` PydanticCustomError that names the driver and the key:
    an unknown key with the keys the driver takes, a bad value with what is wrong."""
    try:
        model = options_model(driver)
    except ConfigError as exc:
        raise PydanticCustomError("driver_options", str(exc)) from None
    try:
        return model.model_validate(dict(table))
    except ValidationError as exc:
        raise PydanticCustomError("driver_options", describe_options_error(driver, model, exc)) from None


def describe_options_error(driver: str, model: type[DriverOptions], exc: ValidationError) -> str:
    """One line for the first problem of a driver's options (and how many more there are)."""
    errors = exc.errors()
    first = errors[0]
    key = ".".join(str(p) for p in first.get("loc", ())) or "(options)"
    allowed = ", ".join(sorted(model.model_fields))
    if first.get("type") == "extra_forbidden":
        text = f"driver {driver!r} has no option {key!r} (its options: {allowed})"
    elif first.get("type") == "missing":
        text = f"driver {driver!r} needs option {key!r}"
    else:
        msg = str(first.get("msg", "invalid value")).removeprefix("Value error, ")
        got = f" (got {first['input']!r})" if "input" in first and first.get("type") != "model_type" else ""
        text = f"driver {driver!r} option {key!r}: {msg}{got}" if key != "(options)" else f"driver {driver!r}: {msg}"
    if len(errors) > 1:
        text += f" (and {len(errors) - 1} more problem{'s' if len(errors) > 2 else ''})"
    return text


def options_table(model: type[DriverOptions]) -> str:
    """The Markdown table of a driver's options (key, type, default, range, what it is) as docs/hardware.md shows
    it (``scripts/hardware_options.py`` writes them there; ``tests/drivers/test_drivers_options.py`` holds them)."""
    rows = ["| key | type | default | range | what |", "|---|---|---|---|---|"]
    for key, field in model.model_fields.items():
        default = "required" if field.is_required() else f"`{field.get_default(call_default_factory=True)!r}`"
        what = (field.description or "").replace("|", "\\|")
        rows.append(f"| `{key}` | {_type_name(field.annotation)} | {default} | {_range(field.metadata)} | {what} |")
    return "\n".join(rows)


OPTIONS_BLOCK = re.compile(r"(<!-- options: (?P<driver>[\w.-]+) -->\n)(?P<body>.*?)(<!-- /options -->)", re.S)


def fill_options_tables(markdown: str) -> str:
    """``markdown`` with each ``<!-- options: DRIVER -->`` … ``<!-- /options -->`` block holding that driver's
    current :func:`options_table`."""
    return OPTIONS_BLOCK.sub(lambda m: m.group(1) + options_table(options_model(m.group("driver"))) + "\n"
                             + m.group(4), markdown)


def _type_name(annotation: object) -> str:
    if get_origin(annotation) is Literal:
        return "one of " + ", ".join(repr(a) for a in get_args(annotation))
    parts = get_args(annotation) if isinstance(annotation, UnionType) else (annotation,)
    return " or ".join("None" if p is type(None) else getattr(p, "__name__", str(p)) for p in parts)


def _range(metadata: list[object]) -> str:
    bounds = []
    for item in metadata:
        for attr, sign in (("ge", "≥"), ("gt", ">"), ("le", "≤"), ("lt", "<")):
            value = getattr(item, attr, None)
            if value is not None:
                bounds.append(f"{sign} {value}")
    return ", ".join(bounds)
