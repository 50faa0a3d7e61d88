"""The layout's rules, checked on the source: imports run one way (main -> api -> jobs -> compute -> solver),
only app/api and app/main import FastAPI or Starlette, and the worker side imports neither the web nor the
database layer."""

from __future__ import annotations

import ast

from .conftest import REPO

APP = REPO / "app"
LAYERS = ["main", "api", "jobs", "compute"]  # each may import only the ones after it (and app.settings, examples)


def _imports(path) -> set[str]:
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            names |= {f"{node.module}.{a.name}" for a in node.names}
    return names


def _layer(path) -> str | None:
    rel = path.relative_to(APP).parts
    if rel[0] == "main.py":
        return "main"
    return rel[0] if rel[0] in LAYERS else None


def test_only_the_api_and_main_import_fastapi_or_starlette():
    for path in APP.rglob("*.py"):
        if _layer(path) in ("api", "main"):
            continue
        web = {m for m in _imports(path) if m.split(".")[0] in ("fastapi", "starlette", "uvicorn")}
        if path.name == "cli.py":
            web.discard("uvicorn")  # `ncs-design serve` starts the server
        assert not web, (path, web)


def test_imports_run_one_way():
    for path in APP.rglob("*.py"):
        layer = _layer(path)
        if layer is None:
            continue
        allowed_above = LAYERS[LAYERS.index(layer):]
        for module in _imports(path):
            parts = module.split(".")
            if parts[0] != "app" or len(parts) < 2:
                continue
            target = "main" if parts[1] == "main" else parts[1]
            if target in LAYERS:
                assert target in allowed_above, f"{path.relative_to(REPO)} imports {module} (against the layering)"


def test_the_worker_side_needs_no_database():
    for path in (APP / "compute").rglob("*.py"):
        assert not {m for m in _imports(path) if m.split(".")[0] == "sqlalchemy"}, path
