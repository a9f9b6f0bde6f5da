"""What an admin of a bench sets while the service runs (``GET/PUT /api/settings``): the dashboard session's
lifetime, the sign-in lockout, the pages' default language and the bench's display name. Validated here, once,
then typed; kept in the run store (one row per bench, :meth:`BenchSettingsRecords.put_bench_settings`); every change
audited with the fields before and after."""

from __future__ import annotations

import logging
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from tcms_daq.store import Store
from tcms_daq.store.people import SESSION_LIFETIME_S

log = logging.getLogger(__name__)

Language = Literal["en", "zh"]


class AdminSettings(BaseModel):
    """A bench's run-time settings; each field has the default a bench starts with."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)

    session_lifetime_h: float = Field(
        default=SESSION_LIFETIME_S / 3600.0, ge=0.25, le=72.0,
        description="how long a dashboard sign-in lasts, hours (a shift: 12)")
    lockout_failures_per_user: int = Field(
        default=5, ge=1, le=100, description="failed sign-ins of one user name within lockout_s that lock it")
    lockout_failures_per_address: int = Field(
        default=20, ge=1, le=1000, description="failed sign-ins from one address within lockout_s that lock it")
    lockout_s: int = Field(
        default=300, ge=10, le=86_400,
        description="the window failures are counted in, s; a lock lasts until the oldest of them is this old")
    default_language: Language | None = Field(
        default=None, description="the pages' language when the user chose none (null: the browser's, else "
        "English); reports and certificates without ?lang=")
    bench_display_name: str | None = Field(
        default=None, min_length=1, max_length=80, pattern=r"^[^\x00-\x1f]+$",
        description="the bench's name on the pages (null: the bench configuration's name)")

    @property
    def session_lifetime_s(self) -> float:
        return self.session_lifetime_h * 3600.0

    def changed_from(self, before: AdminSettings) -> tuple[str, str]:
        """(before, after) of the fields that differ, as ``name=value`` text for the audit trail."""
        old, new = before.model_dump(), self.model_dump()
        names = [k for k in new if new[k] != old[k]]
        return (" ".join(f"{k}={old[k]}" for k in names), " ".join(f"{k}={new[k]}" for k in names))


class SettingsChange(BaseModel):
    """``PUT /api/settings``: the fields to change (others keep their value; null sets a field back to its
    default where the default is null). 422 naming the field for a value out of range or an unknown field."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    session_lifetime_h: float | None = None
    lockout_failures_per_user: int | None = None
    lockout_failures_per_address: int | None = None
    lockout_s: int | None = None
    default_language: Language | None = None
    bench_display_name: str | None = None

    def applied_to(self, current: AdminSettings) -> AdminSettings:
        """``current`` with this change; ValidationError (naming the field) when a value is out of range."""
        change = self.model_dump(exclude_unset=True)
        nullable = {"default_language", "bench_display_name"}
        for name, value in change.items():
            if value is None and name not in nullable:
                raise ValueError(f"{name}: may not be null")
        return AdminSettings.model_validate({**current.model_dump(), **change})


def stored_settings(store: Store) -> AdminSettings:
    """The settings the run store keeps for its bench (defaults where none were set). A stored document that no
    longer validates (written by another version) is logged and replaced by the defaults rather than stopping
    every sign-in."""
    try:
        return AdminSettings.model_validate(store.bench_settings())
    except ValidationError as exc:
        log.warning("the stored bench settings are not valid (%s); using the defaults", exc.errors()[0]["msg"])
        return AdminSettings()
