"""Process settings from the environment, read in one place (pydantic-settings; prefix ``TCMS_``).

``TCMS_CONFIG_DIR`` — a directory searched first for config files named without a path (default: the packaged
defaults only); ``TCMS_DATA_DIR`` — the run store directory (default ``./data``); ``TCMS_API_TOKEN`` — the
service's bearer token when the config has none. Only the composition roots (CLI, service) read them.
"""

from __future__ import annotations

from pathlib import Path

from pydantic_settings import BaseSettings, SettingsConfigDict

DEFAULT_DATA_DIR = Path("data")


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="TCMS_", extra="ignore")

    config_dir: Path | None = None
    data_dir: Path = DEFAULT_DATA_DIR
    api_token: str | None = None


def read_settings() -> Settings:
    """The settings of this process, read from the environment now (tests change it between calls)."""
    return Settings()
