"""Application factory."""

from __future__ import annotations

import logging
import threading
from collections import OrderedDict
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import FastAPI, Request
from fastapi.openapi.utils import get_openapi
from fastapi.openapi.docs import get_redoc_html, get_swagger_ui_html, get_swagger_ui_oauth2_redirect_html
from fastapi.responses import FileResponse
from fastapi.staticfiles import StaticFiles

from app.api import problems
from app import web
from app.jobs import store
from app.jobs.database import Database, run_migrations
from app.jobs.dispatcher import make_dispatcher
from app.api.middleware import BodySizeLimit, BodyTimeout, JsonBodiesOnly
from app.api import analyses, channels, designs, health, margin_routes, problem_pages, simulations
from app.settings import Settings
from app.jobs.sync_pool import SyncPool
from app.jobs.watch import JobWatch

log = logging.getLogger("app")

DESCRIPTION = """
Design and certify **networked predictive controllers for switched plants** with bounded packet losses
(Routh, Das, Das, Pan: *Stabilization Based Networked Predictive Controller Design for Switched Plants*).

* `POST /v1/designs` queues a design job (202 + `Location`); poll `GET /v1/designs/{id}` or stream
  `GET /v1/designs/{id}/events` until `succeeded`, then read `result.gains` (n_drop matrices m x n, K_1 first)
  and the re-checked Lyapunov certificate.
* `GET /v1/designs/{id}/trace` simulates the designed loop (seeded, reproducible).
* `GET /v1/designs/{id}/gains.mat` (or `.m`) exports the design for MATLAB/Octave; `.../controller.zip` as C99
  code of the controller and the actuator's buffer; `.../problem.dat-s` is its SDP in SDPA format.
* `POST /v1/analyses` checks given gains; `POST /v1/simulations` simulates them.

Notation in the schemas: n states, m inputs, r plant modes, n_drop = N (at most N - 1 consecutive losses),
h the sampling period (s). Rates are per sample (lambda) and per second (lambda^(1/h)).

Errors are RFC 9457 `application/problem+json`; `errors[].pointer` names the offending field and `type` is a page
of this service (`/problems/{slug}`) saying how to fix it.
"""


class LRU:
    """Recent answers (bytes), bounded by count and by their total size: a 10,000-step trace of a 20-mode design
    is tens of MB, so a count alone let one key grow the service by gigabytes."""

    def __init__(self, size: int = 128, max_bytes: int = 64 * 2**20):
        self.size = size
        self.max_bytes = max_bytes
        self.nbytes = 0
        self._d: OrderedDict = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key):
        with self._lock:
            if key in self._d:
                self._d.move_to_end(key)
                return self._d[key]
            return None

    def __len__(self) -> int:
        return len(self._d)

    def put(self, key, value) -> None:
        size = len(value)
        with self._lock:
            old = self._d.pop(key, None)
            if old is not None:
                self.nbytes -= len(old)
            if size > self.max_bytes // 4:  # one answer may not push out the whole cache
                return
            self._d[key] = value
            self.nbytes += size
            while len(self._d) > self.size or self.nbytes > self.max_bytes:
                _, dropped = self._d.popitem(last=False)
                self.nbytes -= len(dropped)


def _docs_static_dir() -> Path:
    import fastapi_offline

    return Path(fastapi_offline.__file__).parent / "static"


def _problem_openapi(spec: dict) -> dict:
    """Document every error response as the problem+json it really is (not FastAPI's default 422 schema)."""
    from app.api.schemas import Problem

    components = spec.setdefault("components", {}).setdefault("schemas", {})
    problem_schema = Problem.model_json_schema(ref_template="#/components/schemas/{model}")
    components.update(problem_schema.pop("$defs", {}))
    components["Problem"] = problem_schema
    ref = {"$ref": "#/components/schemas/Problem"}
    for path in spec.get("paths", {}).values():
        for op in path.values():
            for code, resp in op.get("responses", {}).items():
                if code[:1] in ("4", "5"):
                    resp["content"] = {"application/problem+json": {"schema": ref}}
                    if code == "422" and resp.get("description") == "Validation Error":
                        resp["description"] = "Invalid request: problem+json whose errors[] name the fields"
    components.pop("HTTPValidationError", None)
    components.pop("ValidationError", None)
    return spec


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or Settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        run_migrations(settings.database_url, settings.alembic_dir)
        db = Database(settings.database_url, settings.database_busy_timeout)
        app.state.db = db
        app.state.sync_pool = SyncPool(settings.sync_workers, settings.sync_time_limit,
                                       settings.worker_memory_mb)
        app.state.dispatcher = None
        if settings.run_dispatcher:
            app.state.dispatcher = make_dispatcher(db, settings, on_finished=app.state.job_watch.finished_many)
            app.state.dispatcher.start()
        try:
            yield
        finally:
            if app.state.dispatcher is not None:
                app.state.dispatcher.stop()
            app.state.sync_pool.shutdown()
            db.dispose()

    app = FastAPI(
        title="ncs-design",
        version="0.1.0",
        description=DESCRIPTION,
        lifespan=lifespan,
        docs_url=None,
        redoc_url=None,
        # operationIds are the handler names (submit_design, get_design, ...): readable in generated clients.
        generate_unique_id_function=lambda route: route.name,
    )
    app.state.settings = settings
    app.state.trace_cache = LRU(128, settings.cache_max_bytes)
    # Jobs other replicas finish are found by one batched read for all waiters (app.jobs.watch); the jobs this
    # process's dispatcher holds are left out of it: it tells their waiters itself.
    app.state.job_watch = JobWatch(
        lambda ids: store.finished_among(app.state.db, ids),
        held=lambda ids: app.state.dispatcher.holds(ids) if getattr(app.state, "dispatcher", None) else ())
    problems.install(app)
    app.add_middleware(BodySizeLimit, limit=settings.max_body_bytes)
    app.add_middleware(BodyTimeout, seconds=settings.body_timeout)
    app.add_middleware(JsonBodiesOnly, paths=frozenset({"/v1/designs", "/v1/margins", "/v1/analyses",
                                                        "/v1/simulations"}))
    app.include_router(designs.router)
    app.include_router(simulations.router)
    app.include_router(analyses.router)
    app.include_router(channels.router)
    app.include_router(margin_routes.router)
    app.include_router(health.router)
    app.include_router(problem_pages.router)

    def openapi():
        if app.openapi_schema is None:
            app.openapi_schema = _problem_openapi(get_openapi(
                title=app.title, version=app.version, description=app.description, routes=app.routes))
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]

    # Swagger UI and ReDoc from local files (no CDN): /docs works offline.
    static = "/static/docs"
    app.mount(static, StaticFiles(directory=_docs_static_dir()), name="docs-static")

    @app.get("/docs", include_in_schema=False)
    def swagger_ui(request: Request):
        return get_swagger_ui_html(
            openapi_url=app.openapi_url, title="ncs-design - API docs",
            swagger_js_url=f"{static}/swagger-ui-bundle.js", swagger_css_url=f"{static}/swagger-ui.css",
            swagger_favicon_url=f"{static}/favicon.png", oauth2_redirect_url="/docs/oauth2-redirect",
        )

    @app.get("/docs/oauth2-redirect", include_in_schema=False)
    def swagger_redirect():
        return get_swagger_ui_oauth2_redirect_html()

    # The design page (app/web): static files, a client of the public /v1 API like any other.
    app.mount("/static/page", StaticFiles(directory=web.STATIC), name="page-static")

    @app.get("/", include_in_schema=False)
    def design_page():
        return FileResponse(web.STATIC / "index.html", media_type="text/html; charset=utf-8")

    @app.get("/redoc", include_in_schema=False)
    def redoc():
        return get_redoc_html(openapi_url=app.openapi_url, title="ncs-design - API reference",
                              redoc_js_url=f"{static}/redoc.standalone.js", redoc_favicon_url=f"{static}/favicon.png",
                              with_google_fonts=False)

    return app
