"""Liveness, Prometheus metrics and the dashboard page."""

from __future__ import annotations

import json
from pathlib import Path

from fastapi import APIRouter, Request
from fastapi.responses import FileResponse, PlainTextResponse, Response

from tcms_daq.service.admin_settings import stored_settings
from tcms_daq.service.deps import Store
from tcms_daq.service.metrics import render
from tcms_daq.service.schemas import Health

STATIC_DIR = Path(__file__).resolve().parents[1] / "static"

router = APIRouter(tags=["service"])


@router.get("/api/health", response_model=Health)
def health() -> Health:
    """200 while the service runs (open even when reads need the token)."""
    return Health(status="ok")


@router.get("/metrics", response_class=PlainTextResponse)
def metrics(request: Request) -> PlainTextResponse:
    """Prometheus text format: acquisition rate, live clients and drops, runs by status, active test."""
    return PlainTextResponse(render(request.app.state.metrics), media_type="text/plain; version=0.0.4; charset=utf-8")


@router.get("/", include_in_schema=False)
def dashboard() -> FileResponse:
    return FileResponse(STATIC_DIR / "index.html", media_type="text/html")


@router.get("/fleet", include_in_schema=False)
def fleet() -> FileResponse:
    """The fleet page: every bench's runs (search, downloads, overlay of two loops) and SPC."""
    return FileResponse(STATIC_DIR / "fleet.html", media_type="text/html")


@router.get("/favicon.ico", include_in_schema=False)
def favicon() -> FileResponse:
    """The pages' icon (browsers ask for /favicon.ico whatever the page links)."""
    return FileResponse(STATIC_DIR / "favicon.svg", media_type="image/svg+xml")


@router.get("/i18n/messages.js", include_in_schema=False)
def messages_js(store: Store) -> Response:
    """The pages' message catalogues, one per language (tcms_daq/service/messages.py), and the bench's default
    language (its admin's setting; null: the browser's), as a script."""
    from tcms_daq.service.messages import LANGUAGES, SOURCE_PATTERNS, catalogue

    doc = {lang: catalogue(lang) for lang in LANGUAGES}
    body = ("window.TCMS_MESSAGES = " + json.dumps(doc, ensure_ascii=False, sort_keys=True) + ";\n"
            "window.TCMS_DEFAULT_LANG = " + json.dumps(stored_settings(store).default_language) + ";\n"
            "window.TCMS_SOURCE_PATTERNS = " + json.dumps([[p.replace("(?P<", "(?<"), k] for p, k in SOURCE_PATTERNS],
                                                          ensure_ascii=False) + ";\n")
    return Response(body, media_type="text/javascript; charset=utf-8", headers={"Cache-Control": "no-cache"})
