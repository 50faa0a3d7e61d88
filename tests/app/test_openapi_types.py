"""A walk of the OpenAPI schema: every success response of every operation is typed and documented.

* every 2xx response of every operation has a schema for each of its media types, and no schema reachable from
  it is empty (`{}`) or an untyped free-form object (an object without properties or typed values);
* every property of every object reachable from a response has a description;
* every operationId is a snake_case handler name;
* the plant input is the discriminated union of its three kinds (not `any`).
"""

from __future__ import annotations

import re

import pytest

from app import create_app

SNAKE = re.compile(r"^[a-z][a-z0-9]*(_[a-z0-9]+)*$")


@pytest.fixture(scope="module")
def spec():
    return create_app().openapi()


def _resolve(spec, schema):
    while "$ref" in schema:
        name = schema["$ref"].rsplit("/", 1)[1]
        schema = spec["components"]["schemas"][name]
    return schema


def _walk(spec, schema, where, problems, seen):
    """Check one schema and everything it reaches; ``problems`` collects what is untyped or undocumented."""
    if not isinstance(schema, dict) or not schema:
        problems.append(f"{where}: empty schema")
        return
    if "$ref" in schema:
        ref = schema["$ref"]
        if ref in seen:
            return
        seen.add(ref)
        return _walk(spec, _resolve(spec, schema), f"{where}->{ref.rsplit('/', 1)[1]}", problems, seen)
    for key in ("anyOf", "oneOf", "allOf"):
        for i, sub in enumerate(schema.get(key, [])):
            _walk(spec, sub, f"{where}.{key}[{i}]", problems, seen)
    if any(k in schema for k in ("anyOf", "oneOf", "allOf")):
        return
    typ = schema.get("type")
    if typ is None and "const" not in schema and "enum" not in schema:
        problems.append(f"{where}: no type")
        return
    if typ == "array":
        if "items" not in schema:
            problems.append(f"{where}: array without item type")
        else:
            _walk(spec, schema["items"], f"{where}[]", problems, seen)
    if typ == "object":
        props = schema.get("properties") or {}
        extra = schema.get("additionalProperties")
        if not props and not isinstance(extra, dict):
            problems.append(f"{where}: free-form object without properties or typed values")
        if isinstance(extra, dict):
            _walk(spec, extra, f"{where}{{}}", problems, seen)
        for name, prop in props.items():
            if not (prop.get("description") or _resolve(spec, prop).get("description") and "$ref" in prop):
                problems.append(f"{where}.{name}: no description")
            _walk(spec, prop, f"{where}.{name}", problems, seen)


def _operations(spec):
    for path, ops in spec["paths"].items():
        for method, op in ops.items():
            yield path, method, op


def test_every_success_response_is_typed_and_every_field_documented(spec):
    problems: list[str] = []
    checked = 0
    for path, method, op in _operations(spec):
        ok = {code: r for code, r in op["responses"].items() if code.startswith("2")}
        assert ok, f"{method} {path} documents no success response"
        for code, resp in ok.items():
            content = resp.get("content")
            assert content, f"{method.upper()} {path} {code}: no content documented"
            for media, body in content.items():
                _walk(spec, body.get("schema") or {}, f"{method.upper()} {path} {code} {media}", problems, set())
                checked += 1
    assert not problems, "\n".join(problems)
    assert checked >= 20


def test_operation_ids_are_snake_case_handler_names(spec):
    ids = [op["operationId"] for _, _, op in _operations(spec)]
    assert len(ids) == len(set(ids))
    bad = [i for i in ids if not SNAKE.match(i) or "_v1_" in i or len(i) > 30]
    assert not bad, bad
    for name in ("submit_design", "get_design", "list_designs", "cancel_design", "design_events", "design_trace",
                 "design_gains_mat", "design_gains_m", "submit_margin", "get_margin", "list_margins",
                 "run_analysis", "run_simulation"):
        assert name in ids, name


def test_job_result_and_sync_answers_are_typed(spec):
    schemas = spec["components"]["schemas"]
    result = schemas["DesignJob"]["properties"]["result"]
    assert "DesignResult" in str(result)
    assert "MarginResult" in str(schemas["MarginJob"]["properties"]["result"])
    gains = schemas["DesignResult"]["properties"]["gains"]["description"]
    assert "n_drop x m x n" in gains and "K_q" in gains
    assert "r x n_drop" in schemas["DesignResult"]["properties"]["spectral_radii"]["description"]
    assert "lambda_max(P)" in schemas["Certificate"]["properties"]["margin"]["description"]
    assert "per second" in schemas["DesignResult"]["properties"]["decay_rate_per_second"]["description"]
    for kind in ("common_quadratic", "switched", "farkas", "uncontrollable"):
        assert kind in schemas["Certificate"]["properties"]["kind"]["description"]
    for path, model in (("/v1/analyses", "AnalysisReport"), ("/v1/simulations", "Simulation")):
        ref = spec["paths"][path]["post"]["responses"]["200"]["content"]["application/json"]["schema"]["$ref"]
        assert ref.endswith("/" + model)
    trace = spec["paths"]["/v1/designs/{job_id}/trace"]["get"]["responses"]["200"]["content"]
    assert trace["application/json"]["schema"]["$ref"].endswith("/Trace")


def test_plant_is_a_union_of_three_kinds(spec):
    plant = spec["components"]["schemas"]["DesignRequest"]["properties"]["plant"]
    assert plant["discriminator"]["propertyName"] == "kind"
    assert sorted(plant["discriminator"]["mapping"]) == ["continuous", "dc_motor", "discrete"]
    assert plant.get("description")
    for kind in ("ContinuousPlant", "DiscretePlant", "DcMotorPlant"):
        props = spec["components"]["schemas"][kind]["properties"]
        assert {"state_names", "input_names", "units"} <= set(props)
