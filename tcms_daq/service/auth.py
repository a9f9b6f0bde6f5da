"""Bearer-token auth for mutating endpoints (DESIGN §7).

The token comes from config, else ``TCMS_API_TOKEN``; with neither, a random one is generated at start and
printed with the dashboard URL (as Jupyter does). Read endpoints stay open.
"""

from __future__ import annotations

import logging
import os
import re
import secrets

from fastapi import HTTPException, Request, status

TOKEN_ENV = "TCMS_API_TOKEN"


def resolve_token(configured: str | None) -> tuple[str, str]:
    """(token, where it came from: 'config' | 'environment' | 'generated')."""
    if configured:
        return configured, "config"
    env = os.environ.get(TOKEN_ENV, "").strip()
    if env:
        return env, "environment"
    return secrets.token_urlsafe(24), "generated"


def require_token(request: Request) -> None:
    """FastAPI dependency: 401 unless ``Authorization: Bearer <token>`` matches the service token."""
    expected: str = request.app.state.api_token
    header = request.headers.get("authorization", "")
    scheme, _, given = header.partition(" ")
    # compared as UTF-8 bytes: compare_digest refuses str with non-ASCII characters (a 500 otherwise)
    if scheme.lower() != "bearer" or not given or not secrets.compare_digest(given.strip().encode("utf-8"),
                                                                               expected.encode("utf-8")):
        raise HTTPException(
            status_code=status.HTTP_401_UNAUTHORIZED,
            detail="missing or invalid bearer token (Authorization: Bearer <token>)",
            headers={"WWW-Authenticate": "Bearer"},
        )


_TOKEN_IN_QUERY = re.compile(r"(?i)([?&]token=)[^&\s]*")


class RedactTokenInAccessLog(logging.Filter):
    """Masks ``?token=…`` in uvicorn's access log lines (the dashboard URL carries the token)."""

    def filter(self, record: logging.LogRecord) -> bool:
        if isinstance(record.args, tuple):
            record.args = tuple(_TOKEN_IN_QUERY.sub(r"\1***", a) if isinstance(a, str) else a for a in record.args)
        elif isinstance(record.msg, str):
            record.msg = _TOKEN_IN_QUERY.sub(r"\1***", record.msg)
        return True
