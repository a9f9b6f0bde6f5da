"""People: sign in and out (the dashboard's session), who am I, users and their API tokens (admin), and the
audit trail (read only: nothing in the API changes or removes an entry)."""

from __future__ import annotations

import asyncio
import time
from datetime import datetime
from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Query, Request, Response
from fastapi import Path as PathParam

from tcms_daq.service.admin_settings import stored_settings
from tcms_daq.service.auth import SESSION_COOKIE, Principal, authenticate, require
from tcms_daq.service.deps import Store, errors
from tcms_daq.service.routes.tests import unix_seconds
from tcms_daq.service.runner import RequestRejected
from tcms_daq.service.schemas import AuditView, ErrorBody, Login, Me, NewToken, NewUser, TokenIssued, UserView
from tcms_daq.service.signin_limit import SignInLimiter
from tcms_daq.service.testruns import UnknownRun
from tcms_daq.service.users import audit, check_login, hash_password, new_api_token, new_secret
from tcms_daq.store import StoreError
from tcms_daq.store.people import AuditQuery

router = APIRouter(prefix="/api", tags=["people"])

UserName = Annotated[str, PathParam(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9][A-Za-z0-9._@-]*$")]


def _me(principal: Principal) -> Me:
    from tcms_daq.service.auth import RIGHTS

    return Me(name=principal.name, role=principal.role, via=principal.via,
              rights=sorted(r for r in RIGHTS if principal.may(r)))


@router.post("/login", response_model=Me, responses={
    **errors(401, 422), 429: {"model": ErrorBody, "description": "too many failed sign-ins of this user or from this "
                              "address (the admin's lockout settings); Retry-After: seconds to wait"}})
def login(body: Login, store: Store, request: Request, response: Response) -> Me:
    """Sign in with a user's name and password: sets the dashboard's session cookie (HttpOnly, SameSite=Strict,
    the admin's session lifetime). 401 for a wrong name or password or a disabled user (each failure is
    audited); 429 with ``Retry-After`` while the user or the address is locked out after repeated failures (the
    lock is audited when it begins)."""
    limiter: SignInLimiter = request.app.state.signin_limiter
    policy = stored_settings(store)
    address = request.client.host if request.client else "unknown"
    name = body.name[:64]
    wait_s = limiter.retry_after_s(name, address, time.monotonic(), policy)
    if wait_s is not None:
        raise HTTPException(status_code=429, headers={"Retry-After": str(wait_s)},
                            detail=f"too many failed sign-ins of {name!r} or from {address}: try again in "
                                   f"{wait_s} s")
    if not check_login(store, body.name, body.password):
        audit(store, name, "user.login_failed", detail=f"from {address}")
        now = time.monotonic()
        limiter.failed(name, address, now)
        locked_s = limiter.retry_after_s(name, address, now, policy)
        if locked_s is not None:
            audit(store, name, "user.login_locked",
                  detail=f"from {address}: sign-in refused for {locked_s} s after repeated failures")
        raise HTTPException(status_code=401, detail="wrong user name or password (or the user is disabled)")
    limiter.succeeded(name)
    user = store.user(body.name)
    assert user is not None
    session_id = new_secret()
    store.add_session(user.name, session_id, policy.session_lifetime_s)
    response.set_cookie(SESSION_COOKIE, session_id, max_age=int(policy.session_lifetime_s), httponly=True,
                        samesite="strict", path="/")
    audit(store, Principal(user.name, user.role, "session"), "user.login")
    return _me(Principal(user.name, user.role, "session"))


@router.post("/logout", status_code=204, responses=errors(401))
def logout(store: Store, request: Request, response: Response,
           principal: Annotated[Principal, Depends(require("test.abort"))]) -> Response:
    """End the dashboard's session (its cookie is cleared)."""
    session_id = request.cookies.get(SESSION_COOKIE)
    if session_id:
        store.end_session(session_id)
    answer = Response(status_code=204)
    answer.delete_cookie(SESSION_COOKIE, path="/")
    return answer


@router.get("/me", response_model=Me, responses=errors(401))
def me(request: Request) -> Me:
    """Who the credential of this request names (the service token: ``service``, role ``automation``)."""
    return _me(authenticate(request))


@router.get("/users", response_model=list[UserView], responses=errors(401, 403))
def list_users(store: Store, _admin: Annotated[Principal, Depends(require("users.admin"))]) -> list[dict]:
    """Every user with its role (admin)."""
    return [u.summary() for u in store.users()]


@router.post("/users", status_code=201, response_model=UserView, responses=errors(401, 403, 409, 422))
async def add_user(body: NewUser, store: Store,
                   admin: Annotated[Principal, Depends(require("users.admin"))]) -> dict:
    """A new user with a role and a password (admin; kept as an argon2 hash). 409 when the name is taken."""
    from tcms_daq.service.testruns import Conflict

    if store.user(body.name) is not None:
        raise Conflict(f"user {body.name!r} exists already")
    hashed = await asyncio.to_thread(hash_password, body.password)
    user = store.add_user(body.name, body.role, hashed)
    audit(store, admin, "user.add", target=user.name, after=f"role {user.role}")
    return user.summary()


@router.post("/users/{name}/disable", response_model=UserView, responses=errors(401, 403, 404))
def disable_user(name: UserName, store: Store,
                 admin: Annotated[Principal, Depends(require("users.admin"))]) -> dict:
    """Disable a user (admin): its sessions end, its API tokens stop working; its records stay."""
    return _set_disabled(store, admin, name, True)


@router.post("/users/{name}/enable", response_model=UserView, responses=errors(401, 403, 404))
def enable_user(name: UserName, store: Store,
                admin: Annotated[Principal, Depends(require("users.admin"))]) -> dict:
    """Enable a disabled user again (admin)."""
    return _set_disabled(store, admin, name, False)


def _set_disabled(store: Store, admin: Principal, name: str, disabled: bool) -> dict:
    user = store.user(name)
    if user is None:
        raise UnknownRun(f"no user {name!r}")
    changed = store.set_user_disabled(name, disabled)
    audit(store, admin, "user.disable" if disabled else "user.enable", target=name,
          before="disabled" if user.disabled else "enabled", after="disabled" if disabled else "enabled")
    return changed.summary()


@router.post("/users/{name}/tokens", status_code=201, response_model=TokenIssued,
             responses=errors(401, 403, 404, 422))
def issue_token(name: UserName, store: Store, admin: Annotated[Principal, Depends(require("users.admin"))],
                body: NewToken | None = None) -> TokenIssued:
    """A new API token for user ``name``'s scripts (admin); the answer is the only time it is shown."""
    if store.user(name) is None:
        raise UnknownRun(f"no user {name!r}")
    label = body.label if body else ""
    token = new_api_token(store, name, label)
    audit(store, admin, "user.token", target=name, detail=label or None)
    return TokenIssued(user=name, token=token)


@router.get("/audit", response_model=list[AuditView], responses={
    **errors(401, 403, 422), 200: {"description": "the page of entries, newest first",
                                   "headers": {"X-Total-Count": {"description": "entries matching, all pages",
                                                                 "schema": {"type": "integer"}}}}})
def list_audit(store: Store, response: Response, _who: Annotated[Principal, Depends(require("audit.read"))],
               user: Annotated[str | None, Query(min_length=1, max_length=64)] = None,
               action: Annotated[str | None, Query(min_length=1, max_length=64,
                                                   description="an action or its prefix (compensation)")] = None,
               target: Annotated[str | None, Query(min_length=1, max_length=200)] = None,
               since: Annotated[datetime | None, Query(description="at or after (ISO 8601; UTC without a zone)")] = None,
               until: Annotated[datetime | None, Query(description="at or before (ISO 8601; UTC without a zone)")] = None,
               limit: Annotated[int, Query(ge=1, le=1000)] = 100,
               offset: Annotated[int, Query(ge=0, le=2**31 - 1)] = 0) -> list[dict]:
    """The audit trail, newest first, one page at a time (``X-Total-Count`` counts all pages): every test start
    and abort, compensation upload and rollback, bench model change, plan change, user change and failed sign-in,
    with who, when and the version or hash before and after. Read only."""
    try:
        query = AuditQuery(user=user, action=action, target=target, since=unix_seconds(since),
                           until=unix_seconds(until))
    except StoreError as exc:
        raise RequestRejected(str(exc)) from None
    response.headers["X-Total-Count"] = str(store.count_audit(query))
    return [e.summary() for e in store.audit(query, limit, offset)]
