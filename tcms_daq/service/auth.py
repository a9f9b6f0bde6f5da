"""Bearer-token auth for mutating endpoints (DESIGN §7).

The token comes from config, else ``TCMS_API_TOKEN``; with neither, a random one is generated at start and
printed with the dashboard URL (as Jupyter does). Read endpoints are open on loopback; a service reachable from
other machines puts them behind the token too (:class:`ReadTokenMiddleware`, ``tcms serve --read-token``).
"""

from __future__ import annotations

import logging
import re
import secrets
from urllib.parse import parse_qs

from fastapi import Depends, HTTPException, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from starlette.types import ASGIApp, Receive, Scope, Send

from tcms_daq.settings import read_settings


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


_bearer = HTTPBearer(auto_error=False, description="the service token (printed by `tcms serve`)")


def require_token(request: Request, _credentials: HTTPAuthorizationCredentials | None = Depends(_bearer)) -> None:
    """FastAPI dependency: 401 unless ``Authorization: Bearer <token>`` matches the service token. Declared
    through HTTPBearer, so the OpenAPI document names the security scheme of each protected operation."""
    expected: str = request.app.state.api_token
    if not token_matches(bearer_of(request.headers.get("authorization", "")), expected):
        raise HTTPException(
            status_code=status.HTTP_401_UNAUTHORIZED,
            detail="missing or invalid bearer token (Authorization: Bearer <token>)",
            headers={"WWW-Authenticate": "Bearer"},
        )


# reads that stay open when reads need the token: liveness, the dashboard's files, the API description
OPEN_PATHS = ("/api/health", "/static/", "/docs", "/redoc", "/openapi.json")


class ReadTokenMiddleware:
    """Every request under /api/, /metrics and /ws/ needs the token (the ``Authorization`` header, or
    ``?token=`` for a browser's WebSocket or link, which cannot set headers; masked in the access log);
    401 / WebSocket close 1008 otherwise."""

    def __init__(self, app: ASGIApp, token: str):
        self.app = app
        self.token = token

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket") or not self._protected(scope["path"]):
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}
        given = bearer_of(headers.get("authorization", ""))
        if given is None:  # a browser's WebSocket or link cannot set headers
            given = parse_qs(scope.get("query_string", b"").decode("latin-1")).get("token", [None])[0]
        if token_matches(given, self.token):
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
