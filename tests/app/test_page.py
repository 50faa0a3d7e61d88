"""The design page at ``/``: served, every asset it loads is local (works offline), shipped as package data, and
its examples are valid requests (the browser tests in test_page_browser.py run it in Chromium)."""

from __future__ import annotations

import json
import re

import pytest

from app.compute.requests import DesignRequest
from app.examples import PAPER_PLANT
from app.web import STATIC

from .conftest import REPO, running_client


@pytest.fixture(scope="module")
def client(module_db):
    with running_client(module_db) as c:
        yield c


def test_the_page_is_served_at_the_root_and_the_api_stays_where_it_was(client):
    resp = client.get("/")
    assert resp.status_code == 200 and resp.headers["content-type"].startswith("text/html")
    html = resp.text
    for field in ("n_drop", "method", "decay", "objective", "x0", "u_max", "api_key", "submit", "cancel", "jobs"):
        assert f'id="{field}"' in html, field
    assert client.get("/docs").status_code == 200
    assert client.get("/openapi.json").json()["paths"]["/v1/designs"]
    assert "/" not in client.get("/openapi.json").json()["paths"]  # not part of the API


def test_every_asset_is_served_locally(client):
    html = client.get("/").text
    refs = re.findall(r'(?:src|href)="([^"#]+)"', html)
    local = [r for r in refs if r.startswith("/static/page/")]
    assert {"/static/page/page.js", "/static/page/page.css"} <= set(local)
    for ref in local:
        assert client.get(ref).status_code == 200, ref
    # Nothing leaves the service: no absolute URL anywhere in the page's files (links to /docs are relative).
    for path in STATIC.iterdir():
        text = path.read_text()
        text = text.replace('"http://www.w3.org/2000/svg"', "")  # the SVG namespace is a name, never fetched
        assert not re.search(r"(?:https?:)?//[a-z0-9.-]+\.[a-z]{2,}", text, re.I), path.name
        assert "@import" not in text and "fonts.googleapis" not in text
    js = client.get("/static/page/page.js").text
    fetched = set(re.findall(r'"(/v1/[a-z]+)', js)) | set(re.findall(r"`(/v1/[a-z]+)", js))
    assert fetched <= {"/v1/designs", "/v1/margins", "/v1/channels"}, fetched  # only the public API (no private endpoints)


def test_the_page_files_are_package_data():
    # setup.py ships app/web/static/* (flat): a subdirectory would be left out of the wheel.
    assert all(p.is_file() for p in STATIC.iterdir())
    assert re.search(r'"app\.web":\s*\["static/\*"\]', (REPO / "setup.py").read_text())
    assert (REPO / "app" / "web" / "__init__.py").is_file()  # a package, so find_packages() takes it


def test_the_examples_are_valid_design_requests():
    examples = json.loads((STATIC / "examples.json").read_text())
    ids = [e["id"] for e in examples]
    assert {"paper", "dc_motor", "cartpole", "flip"} <= set(ids) and len(ids) == len(set(ids))
    for e in examples:
        DesignRequest.model_validate(e["request"])  # raises on a field the service would reject
    paper = next(e for e in examples if e["id"] == "paper")["request"]["plant"]
    assert all(paper[k] == PAPER_PLANT[k] for k in ("A", "B", "sampling_period", "kind"))


def test_the_readme_shows_the_page_next_to_the_set_up():
    readme = (REPO / "README.md").read_text()
    after_setup = readme.split("<!-- END SETUP -->", 1)[1]
    assert after_setup.lstrip().startswith("## The design page")
    assert "](docs/page.png)" in after_setup.split("\n## ", 2)[1]
    assert (REPO / "docs" / "page.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
