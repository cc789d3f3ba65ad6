"""The browser viewer: one offline page (``GET /viewer``; ``GET /`` redirects to it) served by the service.

The page is plain HTML, CSS and JavaScript modules shipped inside this package (``service/viewer/``,
package data): no CDN, no tile server, no build step. It draws the map's own building footprints and
talks to the ``/v1`` API with ``fetch``; an API key typed into the page stays in the page's memory and
is sent as ``X-API-Key``. These routes are not part of the API reference (``openapi.md``): they serve
the page, not data, and need no key (the page holds no data until the API gives it some).
"""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter, FastAPI, Request
from fastapi.responses import FileResponse, JSONResponse, RedirectResponse
from fastapi.staticfiles import StaticFiles

from service.deps import app_settings

VIEWER_DIR = Path(__file__).resolve().parent / "viewer"
"""``index.html`` and ``static/`` (CSS, JavaScript modules)."""

CONTENT_SECURITY_POLICY = (
    "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' blob: data:; "
    "connect-src 'self'; object-src 'none'; base-uri 'self'; form-action 'none'; frame-ancestors 'none'"
)
"""The page loads nothing from elsewhere (offline by construction) and runs no inline script."""

router = APIRouter(include_in_schema=False)


@router.get("/")
def root() -> RedirectResponse:
    """The service's front door is the viewer."""
    return RedirectResponse("viewer", status_code=307)


@router.get("/viewer")
def viewer_page() -> FileResponse:
    """The viewer's single page."""
    return FileResponse(
        VIEWER_DIR / "index.html",
        media_type="text/html; charset=utf-8",
        headers={"Content-Security-Policy": CONTENT_SECURITY_POLICY, "Cache-Control": "no-cache"},
    )


@router.get("/viewer/config.json")
def viewer_config(request: Request) -> JSONResponse:
    """What the page must know before its first API call: whether it needs an API key."""
    settings = app_settings(request)
    return JSONResponse({"auth_required": settings.auth_enabled}, headers={"Cache-Control": "no-store"})


def install_viewer(app: FastAPI) -> None:
    """Add the viewer's routes and its static files (``/viewer/static``) to ``app``."""
    app.include_router(router)
    app.mount("/viewer/static", StaticFiles(directory=VIEWER_DIR / "static"), name="viewer-static")
