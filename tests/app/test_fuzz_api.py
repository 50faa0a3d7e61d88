"""Property-based API fuzzing: schemathesis generates requests from the service's own OpenAPI schema (every
operation, valid and invalid data) against a real server on loopback with API keys configured.

Zero 5xx, every error a valid problem+json, every response matching its declared status codes, content types,
headers and schema, missing/wrong keys rejected. Bounded: NCS_FUZZ_EXAMPLES examples per operation (default
25, derandomized so CI is reproducible); ``NCS_FUZZ_EXAMPLES=500 NCS_FUZZ_RANDOM=1`` for a long random run.

Excluded check: ``positive_data_acceptance`` -- the JSON schema cannot say that matrices are square, that B has
as many rows as A or that the LMI fits the size limit, so schema-valid bodies are often (rightly) a 422.
"""

from __future__ import annotations

import json
import os
import uuid

import pytest
import schemathesis
from hypothesis import HealthCheck, settings
from schemathesis.specs.openapi.checks import positive_data_acceptance


from bench.harness import Server  # noqa: E402

KEY = "fuzz-" + uuid.uuid4().hex
EXAMPLES = int(os.environ.get("NCS_FUZZ_EXAMPLES", "25"))
RANDOM = bool(os.environ.get("NCS_FUZZ_RANDOM"))

# Small limits: fuzzed designs and analyses stay cheap on a shared CI machine (and hit the limits often).
SERVER_ENV = dict(NCS_WORKERS=1, NCS_API_KEYS=KEY, NCS_MAX_STATES=4, NCS_MAX_INPUTS=3, NCS_MAX_MODES=3,
                  NCS_MAX_N_DROP=4, NCS_MAX_LMI_SIZE=300, NCS_MAX_SIMULATION_STEPS=300,
                  NCS_MAX_ANALYSIS_PRODUCTS=2000, NCS_JOB_TIME_LIMIT=10, NCS_SYNC_TIME_LIMIT=30,
                  NCS_MAX_BODY_BYTES=200_000)


def test_published_schema_is_the_one_fuzzed(fuzz_server):
    import httpx

    assert httpx.get(fuzz_server.base + "/openapi.json", timeout=10).json() == _spec()


@pytest.fixture(scope="module")
def fuzz_server(module_db, tmp_path_factory):
    server = Server(module_db, tmp_path_factory.mktemp("fuzz") / "server.log", **SERVER_ENV)
    try:
        server.wait_ready()
        yield server
    finally:
        server.stop()
        text = server.log_text()
        assert "Traceback" not in text, text[-4000:]
        assert KEY not in text


def _spec() -> dict:
    """The schema the server publishes at /openapi.json (the same settings; no server needed to build it)."""
    from app import create_app
    from app.settings import Settings

    env = {k[4:].lower(): v for k, v in SERVER_ENV.items()}
    return create_app(Settings(database_url="sqlite://", run_dispatcher=False, **env)).openapi()


schema = schemathesis.openapi.from_dict(_spec())


@schemathesis.check
def problem_json(ctx, response, case) -> bool | None:
    """Every 4xx/5xx is RFC 9457 problem+json: its media type, a title, and a status equal to the response's."""
    if response.status_code < 400:
        return None
    ctype = response.headers.get("content-type", [""])
    ctype = ctype[0] if isinstance(ctype, list) else ctype
    assert ctype.startswith("application/problem+json"), f"{response.status_code} with content-type {ctype!r}"
    body = response.json()
    assert isinstance(body, dict) and isinstance(body.get("title"), str), body
    assert body.get("status") == response.status_code, body
    assert isinstance(body.get("type"), str) and isinstance(body.get("detail"), str), body
    for err in body.get("errors") or []:
        assert {"loc", "pointer", "msg", "type"} <= set(err), err
    return None


@schema.parametrize()
@settings(max_examples=EXAMPLES, deadline=None, derandomize=not RANDOM, database=None,
          suppress_health_check=list(HealthCheck))
def test_api_conforms_to_its_schema(case, fuzz_server):
    case.call_and_validate(base_url=fuzz_server.base, headers={"X-API-Key": KEY}, additional_checks=[problem_json],
                           excluded_checks=[positive_data_acceptance], timeout=60)


def test_stateful_workflows_conform_to_their_schema(fuzz_server):
    """The stateful phase: schemathesis follows the links it infers (POST a job -> GET it, its events, cancel)
    with real job ids, so the event streams of real jobs are checked against their schema (issue 20: each
    SSE event violated it, ST108, until the schema described one event)."""
    base = fuzz_server.base

    class Workflow(schema.as_state_machine()):
        def get_call_kwargs(self, case):
            return {"base_url": base, "headers": {"X-API-Key": KEY}, "timeout": 60}

        def validate_response(self, response, case, additional_checks=None, **kwargs):
            case.validate_response(response, additional_checks=[problem_json],
                                   excluded_checks=[positive_data_acceptance])

    Workflow.run(settings=settings(max_examples=EXAMPLES, deadline=None, derandomize=not RANDOM, database=None,
                                   suppress_health_check=list(HealthCheck), stateful_step_count=6))


# -- What schemathesis found, pinned as plain regression tests ---------------------------------------------------

def test_found_body_that_is_not_utf8_is_a_422_malformed_json_not_an_undocumented_400(db_url):
    from .conftest import assert_problem, running_client

    with running_client(db_url, run_dispatcher=False) as c:
        for path in ("/v1/designs", "/v1/analyses", "/v1/simulations", "/v1/margins"):
            resp = c.post(path, content=b"\xff,", headers={"content-type": "application/json"})
            body = assert_problem(resp, 422)
            assert body["type"].endswith("/malformed-json"), body


def test_found_405_lists_every_method_of_the_path_in_allow(db_url):
    from .conftest import assert_problem, running_client

    with running_client(db_url, run_dispatcher=False) as c:
        for path in ("/v1/designs", "/v1/margins"):
            resp = c.options(path)
            assert_problem(resp, 405)
            assert set(resp.headers["allow"].split(", ")) >= {"GET", "POST"}, resp.headers
        assert c.delete("/v1/designs/00000000-0000-4000-8000-000000000000").headers["allow"] == "GET, HEAD"


def test_found_huge_list_offset_is_a_422_not_a_500(db_url):
    """A random schemathesis run (500 examples) sent offset=167830852003322807713792: an integer overflow in the
    database (SQLite and PostgreSQL) and a 500. Offsets are now bounded by the schema."""
    from .conftest import assert_problem, running_client

    with running_client(db_url, run_dispatcher=False) as c:
        for path in ("/v1/designs", "/v1/margins"):
            assert_problem(c.get(path, params={"offset": 167830852003322807713792}), 422, "/offset")
            assert_problem(c.get(path, params={"offset": 2**31}), 422, "/offset")
            assert c.get(path, params={"offset": 2**31 - 1}).json()["items"] == []


def test_found_every_sse_event_of_a_real_job_matches_the_published_event_schema(fuzz_server):
    """Issue 20 (schemathesis ST108 on both /events routes): the schema said `type: string` while OpenAPI 3.1
    tools read the `text/event-stream` schema as the schema of ONE event (event, data, id, retry). Each event of
    a real job's stream, parsed here as an SSE client parses it, must match the published schema."""
    import httpx
    import jsonschema

    from app.examples import PAPER_PLANT

    headers = {"X-API-Key": KEY}
    spec = httpx.get(fuzz_server.base + "/openapi.json", timeout=10).json()
    job = httpx.post(fuzz_server.base + "/v1/designs", headers={**headers, "Prefer": "wait=60"}, timeout=90,
                     json={"plant": PAPER_PLANT, "n_drop": 3, "method": "lmi"}).json()
    for path in ("/v1/designs/{job_id}/events", "/v1/margins/{job_id}/events"):
        event_schema = spec["paths"][path]["get"]["responses"]["200"]["content"]["text/event-stream"]["schema"]
        assert event_schema["type"] == "object", event_schema
    event_schema = spec["paths"]["/v1/designs/{job_id}/events"]["get"]["responses"]["200"]["content"][
        "text/event-stream"]["schema"]
    text = httpx.get(fuzz_server.base + f"/v1/designs/{job['id']}/events", headers=headers, timeout=60).text
    events = []
    for block in text.split("\n\n"):
        fields: dict = {}
        for line in block.splitlines():
            if not line or line.startswith(":"):
                continue
            name, _, value = line.partition(":")
            value = value[1:] if value.startswith(" ") else value
            if name == "data":
                fields["data"] = fields["data"] + "\n" + value if "data" in fields else value
            elif name == "retry":
                fields["retry"] = int(value)
            else:
                fields[name] = value
        if "data" in fields:  # an SSE client dispatches only blocks with data
            events.append(fields)
    assert [e["event"] for e in events][-1] == "end" and len(events) >= 2, events
    for event in events:
        jsonschema.validate(event, event_schema)
        json.loads(event["data"])
