"""The CiA 402 drive's Modbus register map (the packaged ``modbus-drive.toml``): which holding registers carry
which drive object, their type and access, and how 32-bit values are split into 16-bit words."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from tcms_daq.config.loader import packaged_config_dir, read_toml
from tcms_daq.errors import ConfigError

DEFAULT_MAP_PATH = packaged_config_dir() / "modbus-drive.toml"
INPUT_DRIVE_MAP_PATH = packaged_config_dir() / "modbus-input-drive.toml"  # the second axis's velocity drive
COMMON_REGISTERS = ("controlword", "statusword", "error_code", "mode", "mode_display", "position_actual",
                    "rated_torque")
REQUIRED_REGISTERS = (*COMMON_REGISTERS, "target_torque", "max_torque", "torque_actual", "torque_slope")  # loader
#: the registers an input drive's map must have (profile velocity)
VELOCITY_REGISTERS = (*COMMON_REGISTERS, "target_velocity", "velocity_actual", "max_profile_velocity",
                      "profile_acceleration", "profile_deceleration", "quick_stop_deceleration")
TYPES = {"uint16": (1, False), "int16": (1, True), "uint32": (2, False), "int32": (2, True)}


@dataclass(frozen=True)
class RegisterSpec:
    name: str
    address: int
    type: str
    writable: bool
    object_index: int | None = None

    @property
    def words(self) -> int:
        return TYPES[self.type][0]

    @property
    def signed(self) -> bool:
        return TYPES[self.type][1]


@dataclass(frozen=True)
class RegisterMap:
    device_id: int
    word_order: str  # "little" = low word first
    registers: dict[str, RegisterSpec]

    def __getitem__(self, name: str) -> RegisterSpec:
        return self.registers[name]

    def by_address(self) -> dict[int, tuple[RegisterSpec, int]]:
        """address -> (register, word index within it)."""
        table = {}
        for spec in self.registers.values():
            for i in range(spec.words):
                table[spec.address + i] = (spec, i)
        return table

    def encode(self, name: str, value: int) -> list[int]:
        spec = self.registers[name]
        bits = 16 * spec.words
        lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if spec.signed else (0, (1 << bits) - 1)
        if not lo <= value <= hi:
            raise ValueError(f"{value} does not fit {spec.type} register {name!r}")
        raw = value & ((1 << bits) - 1)
        words = [(raw >> (16 * i)) & 0xFFFF for i in range(spec.words)]  # low word first
        return words if self.word_order == "little" else words[::-1]

    def decode(self, name: str, words: list[int]) -> int:
        spec = self.registers[name]
        if len(words) != spec.words:
            raise ValueError(f"register {name!r} needs {spec.words} words, got {len(words)}")
        ordered = list(words) if self.word_order == "little" else list(words)[::-1]
        raw = sum((w & 0xFFFF) << (16 * i) for i, w in enumerate(ordered))
        bits = 16 * spec.words
        if spec.signed and raw & (1 << (bits - 1)):
            raw -= 1 << bits
        return raw


def load_register_map(path: Path | str | None = None, required: tuple[str, ...] = REQUIRED_REGISTERS) -> RegisterMap:
    """Read and validate a register map TOML (default: the packaged ``modbus-drive.toml``); ``required``: the
    registers it must have (the loader's by default, ``VELOCITY_REGISTERS`` for an input drive)."""
    path = Path(path) if path is not None else DEFAULT_MAP_PATH
    data = read_toml(path)
    modbus = data.get("modbus", {})
    word_order = modbus.get("word_order", "little")
    if word_order not in ("little", "big"):
        raise ConfigError(f"{path}: [modbus] word_order must be 'little' or 'big', got {word_order!r}")
    device_id = modbus.get("device_id", 1)
    if not (isinstance(device_id, int) and 0 <= device_id <= 247):
        raise ConfigError(f"{path}: [modbus] device_id must be 0…247, got {device_id!r}")
    registers: dict[str, RegisterSpec] = {}
    for name, entry in data.get("registers", {}).items():
        if not isinstance(entry, dict) or "address" not in entry or "type" not in entry:
            raise ConfigError(f"{path}: [registers] {name} needs address and type")
        if entry["type"] not in TYPES:
            raise ConfigError(f"{path}: [registers] {name}: type must be one of {', '.join(TYPES)}")
        address = entry["address"]
        if not (isinstance(address, int) and 0 <= address <= 0xFFFF):
            raise ConfigError(f"{path}: [registers] {name}: address must be 0…0xFFFF")
        access = entry.get("access", "rw")
        if access not in ("rw", "ro"):
            raise ConfigError(f"{path}: [registers] {name}: access must be 'rw' or 'ro'")
        registers[name] = RegisterSpec(name, address, entry["type"], access == "rw", entry.get("object"))
    missing = [n for n in required if n not in registers]
    if missing:
        raise ConfigError(f"{path}: [registers] lacks {', '.join(missing)}")
    taken: dict[int, str] = {}
    for spec in registers.values():
        for i in range(spec.words):
            other = taken.setdefault(spec.address + i, spec.name)
            if other != spec.name:
                raise ConfigError(f"{path}: registers {other!r} and {spec.name!r} overlap at 0x{spec.address + i:04X}")
    return RegisterMap(device_id, word_order, registers)
