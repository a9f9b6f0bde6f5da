"""Process settings from the environment, read in one place (pydantic-settings; prefix ``TCMS_``).

``TCMS_DATA_DIR`` — the run store directory (default ``./data``); ``TCMS_API_TOKEN`` — the service's bearer token
when the config has none; ``TCMS_STORE_URL`` — the run store (``postgresql://…``; beats the config's ``[store]
url``, ``tcms serve --store`` beats it). Only the composition roots (CLI, service) read them; nothing else reads ``os.environ``.
"""

from __future__ import annotations

from pathlib import Path

from pydantic_settings import BaseSettings, SettingsConfigDict

DEFAULT_DATA_DIR = Path("data")


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="TCMS_", extra="ignore")

    data_dir: Path = DEFAULT_DATA_DIR
    api_token: str | None = None
    store_url: str | None = None


def read_settings() -> Settings:
    """The settings of this process, read from the environment now (tests change it between calls)."""
    return Settings()
