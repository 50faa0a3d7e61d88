"""``GET /problems/{slug}``: the page every problem ``type`` URI points at, saying what went wrong and how to
fix it (RFC 9457 section 3.1.1: a type URI should resolve to human-readable documentation)."""

from __future__ import annotations

import html
import re

from fastapi import APIRouter, Path
from fastapi.responses import HTMLResponse

from app.api.problems import PROBLEM_TYPES, ProblemException

router = APIRouter(prefix="/problems", tags=["problems"])

_HTML = {200: {"description": "An HTML page", "content": {"text/html": {"schema": {"type": "string"}}}}}


def _inline(text: str) -> str:
    """Escape, then render `code` spans."""
    return re.sub(r"`([^`]+)`", r"<code>\1</code>", html.escape(text, quote=False))


def _page(title: str, body: str) -> HTMLResponse:
    return HTMLResponse(
        "<!doctype html><html lang=en><head><meta charset=utf-8>"
        f"<title>{html.escape(title)} - ncs-design</title>"
        "<style>body{font-family:sans-serif;max-width:46em;margin:2em auto;line-height:1.5}"
        "code{background:#eee;padding:0 .2em}</style></head><body>"
        f"{body}<p><a href=\"/problems\">All problem types</a> &middot; <a href=\"/docs\">API docs</a></p>"
        "</body></html>")


@router.get("", summary="Every problem type the service answers with", response_class=HTMLResponse,
            responses=_HTML)
def list_problem_types() -> HTMLResponse:
    items = "".join(f"<li><a href=\"/problems/{slug}\">{html.escape(title)}</a> (<code>{slug}</code>)</li>"
                    for slug, (title, _, _) in PROBLEM_TYPES.items())
    return _page("Problem types", f"<h1>Problem types</h1><p>Every error answer is <code>application/problem+json"
                                  f"</code> (RFC 9457); its <code>type</code> is one of these pages.</p><ul>{items}</ul>")


@router.get("/{slug}", summary="What a problem type means and how to fix it", response_class=HTMLResponse,
            responses={**_HTML, 404: {"description": "No such problem type",
                                      "content": {"application/problem+json": {}}}})
def problem_type_page(slug: str = Path(max_length=64, description="The last segment of a problem's `type`")
                      ) -> HTMLResponse:
    if slug not in PROBLEM_TYPES:
        raise ProblemException(404, f"no problem type {slug!r}; see /problems for the list")
    title, what, fix = PROBLEM_TYPES[slug]
    return _page(title, f"<h1>{html.escape(title)}</h1><p><code>type</code>: <code>/problems/{slug}</code></p>"
                        f"<h2>What happened</h2><p>{_inline(what)}</p><h2>How to fix it</h2><p>{_inline(fix)}</p>")
