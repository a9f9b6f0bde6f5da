"""The admin's run-time settings of this bench (``GET/PUT /api/settings``, the admin right): session lifetime,
sign-in lockout, default language, display name. Each change is audited with the fields before and after."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends
from pydantic import ValidationError

from tcms_daq.service.admin_settings import AdminSettings, SettingsChange, stored_settings
from tcms_daq.service.auth import Principal, require
from tcms_daq.service.deps import Store, errors
from tcms_daq.service.runner import RequestRejected
from tcms_daq.service.users import audit

router = APIRouter(prefix="/api/settings", tags=["people"])


@router.get("", response_model=AdminSettings, responses=errors(401, 403))
def get_settings(store: Store, _admin: Annotated[Principal, Depends(require("settings.edit"))]) -> AdminSettings:
    """This bench's run-time settings (admin); a field never set shows its default."""
    return stored_settings(store)


@router.put("", response_model=AdminSettings, responses=errors(401, 403, 422))
def put_settings(change: SettingsChange, store: Store,
                 admin: Annotated[Principal, Depends(require("settings.edit"))]) -> AdminSettings:
    """Change some of this bench's settings (admin): the fields given take their new value, the others keep
    theirs. 422 naming the field for a value out of range or an unknown field. Audited (``settings.change``) with
    the changed fields before and after; a change that changes nothing is not recorded."""
    before = stored_settings(store)
    try:
        after = change.applied_to(before)
    except ValidationError as exc:
        first = exc.errors()[0]
        raise RequestRejected(f"{'.'.join(map(str, first['loc']))}: {first['msg']}") from None
    except ValueError as exc:
        raise RequestRejected(str(exc)) from None
    if after != before:
        store.put_bench_settings(after.model_dump(), admin.name)
        old, new = after.changed_from(before)
        audit(store, admin, "settings.change", target=store.bench_id or "bench", before=old, after=new)
    return after
