"""Who may do what (DESIGN §7): users with roles, their API tokens and dashboard sessions, and the service token.

A request names its principal by ``Authorization: Bearer <token>`` — the configured service token (the role
``automation``: everything but user administration) or a user's API token — or by the dashboard's session cookie
(after ``POST /api/login``). Each changing route requires one right of :data:`RIGHTS`; a role without it gets 403
naming the role needed. Roles are cumulative: operator < engineer < admin.

The service token comes from config, else ``TCMS_API_TOKEN``; with neither, a random one is generated at start and
printed with the dashboard URL (as Jupyter does). Read endpoints are open on loopback; a service reachable from
other machines puts them behind the token too (:class:`ReadTokenMiddleware`, ``tcms serve --read-token``).
"""

from __future__ import annotations

import logging
import re
import secrets
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any
from urllib.parse import parse_qs

from fastapi import Depends, HTTPException, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from starlette.types import ASGIApp, Receive, Scope, Send

from tcms_daq.settings import read_settings
from tcms_daq.store.people import ROLES


def resolve_token(configured: str | None) -> tuple[str, str]:
    """(token, where it came from: 'config' | 'environment' | 'generated')."""
    if configured:
        return configured, "config"
    env = (read_settings().api_token or "").strip()
    if env:
        return env, "environment"
    return secrets.token_urlsafe(24), "generated"


def token_matches(given: str | None, expected: str) -> bool:
    """Constant-time comparison as UTF-8 bytes (compare_digest refuses str with non-ASCII characters)."""
    if not given:
        return False
    return secrets.compare_digest(given.strip().encode("utf-8"), expected.encode("utf-8"))


def bearer_of(header: str) -> str | None:
    scheme, _, given = header.partition(" ")
    return given if scheme.lower() == "bearer" else None


_bearer = HTTPBearer(auto_error=False, description="the service token (printed by `tcms serve`) or a user's API "
                     "token (`tcms users token NAME`); the dashboard signs in with a session cookie instead")

SESSION_COOKIE = "tcms_session"
#: the configured service token's role: automation may do everything a person may but administer users
AUTOMATION = "automation"
SERVICE_USER = "service"
#: right -> the least role of ROLES that has it (each role has the rights of those before it)
RIGHTS: dict[str, str] = {
    "test.start_plan": "operator",  # start a test from a saved plan
    "test.abort": "operator",
    "audit.read": "operator",
    "test.start": "engineer",  # start a test from a free request (not a saved plan)
    "plan.edit": "engineer",
    "compensation.edit": "engineer",
    "bench_model.apply": "engineer",
    "discrepancy.run": "engineer",
    "users.admin": "admin",
    "settings.edit": "admin",
}
AUTOMATION_RIGHTS = frozenset(r for r, role in RIGHTS.items() if role != "admin")


@dataclass(frozen=True)
class Principal:
    """Who makes a request: a user (``via`` 'token' or 'session') or the service token's automation."""

    name: str
    role: str
    via: str

    def may(self, right: str) -> bool:
        if self.role == AUTOMATION:
            return right in AUTOMATION_RIGHTS
        return self.role in ROLES and ROLES.index(self.role) >= ROLES.index(RIGHTS[right])


def principal_of(state: Any, bearer: str | None, session_id: str | None) -> Principal | None:
    """The principal a bearer token (the service token or a user's API token) or a session cookie names; None
    when neither is valid. ``state``: the app's state (its service token and run store)."""
    if bearer:
        if token_matches(bearer, state.api_token):
            return Principal(SERVICE_USER, AUTOMATION, "token")
        store = getattr(state, "store", None)
        user = store.user_of_token(bearer.strip()) if store is not None else None
        return None if user is None else Principal(user.name, user.role, "token")
    if session_id:
        store = getattr(state, "store", None)
        user = store.user_of_session(session_id) if store is not None else None
        return None if user is None else Principal(user.name, user.role, "session")
    return None


def _unsafe(method: str) -> bool:
    return method.upper() not in ("GET", "HEAD", "OPTIONS")


def authenticate(request: Request) -> Principal:
    """The request's principal; 401 without a valid credential. A session cookie on a changing request also
    needs the header ``X-Requested-By: tcms`` (a page of another site cannot send it: no cross-site forgery)."""
    bearer = bearer_of(request.headers.get("authorization", ""))
    session_id = None if bearer else request.cookies.get(SESSION_COOKIE)
    found = principal_of(request.app.state, bearer, session_id)
    if found is None:
        raise HTTPException(
            status_code=status.HTTP_401_UNAUTHORIZED,
            detail="missing or invalid bearer token or session (Authorization: Bearer <token>, or sign in)",
            headers={"WWW-Authenticate": "Bearer"},
        )
    if found.via == "session" and _unsafe(request.method) and request.headers.get("x-requested-by") != "tcms":
        raise HTTPException(status_code=status.HTTP_403_FORBIDDEN,
                            detail="a signed-in change needs the header X-Requested-By: tcms")
    return found


def require(right: str) -> Callable[..., Principal]:
    """A FastAPI dependency: the principal when it has ``right``; 401 without credentials, 403 naming the role
    needed otherwise. Declared through HTTPBearer, so the OpenAPI document names the security scheme."""
    if right not in RIGHTS:
        raise ValueError(f"unknown right {right!r}")
    needed = RIGHTS[right]

    def check(request: Request, _credentials: HTTPAuthorizationCredentials | None = Depends(_bearer)) -> Principal:
        principal = authenticate(request)
        if not principal.may(right):
            raise HTTPException(status_code=status.HTTP_403_FORBIDDEN,
                                detail=f"{right} needs the role {needed} (or above); {principal.name} is "
                                       f"{principal.role}")
        request.state.principal = principal
        return principal

    check.__name__ = f"require_{right.replace('.', '_')}"
    return check


def require_token(request: Request, _credentials: HTTPAuthorizationCredentials | None = Depends(_bearer)) -> None:
    """FastAPI dependency of a change with no finer right: an engineer's (or the automation's) credential."""
    require("compensation.edit")(request, _credentials)


# reads that stay open when reads need the token: liveness, the dashboard's files, the API description
OPEN_PATHS = ("/api/health", "/static/", "/docs", "/redoc", "/openapi.json")


class ReadTokenMiddleware:
    """Every request under /api/, /metrics and /ws/ needs the token (the ``Authorization`` header, or
    ``?token=`` for a browser's WebSocket or link, which cannot set headers; masked in the access log);
    401 / WebSocket close 1008 otherwise."""

    def __init__(self, app: ASGIApp, token: str):
        self.app = app
        self.token = token  # the service token (kept for callers); users' tokens and sessions come from the store

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket") or not self._protected(scope["path"]):
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}
        given = bearer_of(headers.get("authorization", ""))
        if given is None:  # a browser's WebSocket or link cannot set headers
            given = parse_qs(scope.get("query_string", b"").decode("latin-1")).get("token", [None])[0]
        session_id = None
        for part in headers.get("cookie", "").split(";"):
            key, _, value = part.strip().partition("=")
            if key == SESSION_COOKIE:
                session_id = value
        if token_matches(given, self.token) or principal_of(scope["app"].state, given, session_id) is not None:
            await self.app(scope, receive, send)
            return
        if scope["type"] == "websocket":
            await send({"type": "websocket.close", "code": 1008, "reason": "missing or invalid token"})
            return
        body = b'{"detail":"missing or invalid bearer token (reads need it on this service)"}'
        await send({"type": "http.response.start", "status": 401,
                    "headers": [(b"content-type", b"application/json"), (b"www-authenticate", b"Bearer"),
                                (b"content-length", str(len(body)).encode())]})
        await send({"type": "http.response.body", "body": body})

    @staticmethod
    def _protected(path: str) -> bool:
        if any(path == p or path.startswith(p) for p in OPEN_PATHS):
            return False
        return path.startswith(("/api/", "/ws/")) or path == "/metrics"


_TOKEN_IN_QUERY = re.compile(r"(?i)([?&]token=)[^&\s]*")


def _masked(value: object) -> object:
    return _TOKEN_IN_QUERY.sub(r"\1***", value) if isinstance(value, str) else value


class RedactTokenInAccessLog(logging.Filter):
    """Masks ``?token=…`` in log records: uvicorn's access lines, its WebSocket lines ('"WebSocket /ws/live?token=…"
    [accepted]', on ``uvicorn.error``) and anything else a handler it sits on writes (the dashboard and WebSocket
    URLs carry the token). The arguments keep their shape (uvicorn's access formatter reads them by position)."""

    def filter(self, record: logging.LogRecord) -> bool:
        if isinstance(record.msg, str):
            record.msg = _masked(record.msg)
        if isinstance(record.args, tuple):
            record.args = tuple(_masked(a) for a in record.args)
        elif isinstance(record.args, dict):
            record.args = {k: _masked(v) for k, v in record.args.items()}
        return True


# the loggers a request's URL can reach: uvicorn's (access, WebSocket and error lines) and the websockets library's
URL_LOGGERS = ("uvicorn", "uvicorn.error", "uvicorn.access", "websockets", "websockets.server",
               "websockets.protocol", "tcms_daq")


def redact_tokens_in_logs() -> None:
    """Put :class:`RedactTokenInAccessLog` on every logger a URL can be logged to and on every handler of those
    loggers and of the root logger (records propagated from other loggers pass the handlers). Idempotent; call it
    again after logging was (re)configured (uvicorn configures it when its Config is made)."""
    loggers = [logging.getLogger(name) for name in URL_LOGGERS] + [logging.getLogger()]
    targets: list[logging.Filterer] = [*loggers, *(h for lg in loggers for h in lg.handlers)]
    for target in targets:
        if not any(isinstance(f, RedactTokenInAccessLog) for f in target.filters):
            target.addFilter(RedactTokenInAccessLog())
