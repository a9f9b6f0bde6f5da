"""Typed options, grep level over the AST: the configuration's models keep no unknown keys (no ``extra="allow"`` in
tcms_daq/config), and no driver constructor takes its options as ``**kwargs`` (a driver is built from its options
model, ``drivers/options.py``, checked once when the bench config is read)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: the driver modules: every class in them with a constructor is checked
DRIVER_FILES = sorted((ROOT / "drivers").glob("*.py")) + [ROOT / "sim" / "virtual.py"]
#: constructors that forward what is not a driver's options (named, with why)
FORWARDING = {
    # pyserial port settings (bytesize, parity, stopbits …) each serial driver fixes for its protocol
    "drivers/transport.py:SerialLink.__init__", "drivers/transport.py:SerialInstrument.__init__",
    # the RTU client hands pymodbus' own client settings through
    "drivers/modbus_rtu.py:RtuSerialClient.__init__",
}


def _config_extra_allow(source: str, path: str) -> list[str]:
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Call) and getattr(node.func, "id", getattr(node.func, "attr", None)) == "ConfigDict":
            for kw in node.keywords:
                if kw.arg == "extra" and isinstance(kw.value, ast.Constant) and kw.value.value == "allow":
                    found.append(f"{path}:{node.lineno}")
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "model_config" for t in node.targets) \
                and isinstance(node.value, ast.Dict):
            for k, v in zip(node.value.keys, node.value.values, strict=True):
                if getattr(k, "value", None) == "extra" and getattr(v, "value", None) == "allow":
                    found.append(f"{path}:{node.lineno}")
    return found


def _kwargs_constructors(source: str, path: str) -> list[str]:
    found = []
    for cls in (n for n in ast.walk(ast.parse(source)) if isinstance(n, ast.ClassDef)):
        for item in cls.body:
            if isinstance(item, ast.FunctionDef) and item.name == "__init__" and item.args.kwarg is not None:
                where = f"{path}:{cls.name}.__init__"
                if where not in FORWARDING:
                    found.append(f"{where} (**{item.args.kwarg.arg})")
    return found


def test_no_extra_allow_in_the_configuration():
    found = [hit for p in sorted((ROOT / "tcms_daq" / "config").glob("*.py"))
             for hit in _config_extra_allow(p.read_text(encoding="utf-8"), str(p.relative_to(ROOT)))]
    assert not found, f"models keeping unknown keys (declare the keys): {found}"


def test_no_driver_constructor_takes_its_options_as_kwargs():
    found = [hit for p in DRIVER_FILES
             for hit in _kwargs_constructors(p.read_text(encoding="utf-8"), str(p.relative_to(ROOT)))]
    assert not found, f"driver constructors taking **kwargs (take the driver's options model): {found}"


def test_the_checks_can_fail():
    assert _config_extra_allow('class A(BaseModel):\n    model_config = ConfigDict(extra="allow")\n', "x.py")
    assert _kwargs_constructors("class D:\n    def __init__(self, url, **options: Any):\n        pass\n", "d.py")
