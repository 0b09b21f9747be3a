"""The operator dashboard (docs/DASHBOARD.md): a static page built from ``frontend/`` that asks for a read
token and polls the read routes. The page and its assets need no token."""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter, FastAPI
from fastapi.responses import FileResponse
from fastapi.staticfiles import StaticFiles

__all__ = ["router", "STATIC_DIR", "mount_assets"]

STATIC_DIR = Path(__file__).resolve().parents[1] / "static" / "dashboard"

router = APIRouter(tags=["dashboard"])


@router.get(
    "/dashboard",
    summary="Operator dashboard",
    response_class=FileResponse,
    responses={200: {"description": "The dashboard page.", "content": {"text/html": {}}}},
)
def get_dashboard() -> FileResponse:
    """Coverage, the latest epoch's routes, POI tasks and the fleet recommendation, for a read token."""
    return FileResponse(STATIC_DIR / "index.html", media_type="text/html")


def mount_assets(app: FastAPI) -> None:
    """Serve the page's script, stylesheet and licence notices under /dashboard/assets/."""
    app.mount("/dashboard/assets", StaticFiles(directory=STATIC_DIR / "assets"), name="dashboard-assets")
