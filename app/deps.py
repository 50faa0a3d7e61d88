"""FastAPI dependencies: settings, one database session per request, auth."""

from __future__ import annotations

import hmac
from collections.abc import Iterator

from fastapi import Depends, Request
from sqlalchemy.orm import Session

from app.db import Database
from app.problems import ProblemException
from app.settings import Settings


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


def get_database(request: Request) -> Database:
    return request.app.state.db


def get_session(db: Database = Depends(get_database)) -> Iterator[Session]:
    """Read session for the request (rolled back at the end)."""
    session = db.read_session()
    try:
        yield session
    finally:
        session.rollback()
        session.close()


def require_api_key(request: Request, settings: Settings = Depends(get_settings)) -> None:
    keys = settings.api_keys
    if not keys:
        return
    given = request.headers.get("x-api-key")
    auth = request.headers.get("authorization", "")
    if given is None and auth.lower().startswith("bearer "):
        given = auth[7:].strip()
    if given is None or not any(hmac.compare_digest(given.encode(), k.encode()) for k in keys):
        raise ProblemException(401, "a valid API key is required: send X-API-Key or Authorization: Bearer",
                               title="Unauthorized", headers={"WWW-Authenticate": "Bearer"})
