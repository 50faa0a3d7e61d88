"""``network`` over HTTP: 422s naming /network/..., a design and an analysis on a delay network against the
library, simulations with ages, channels with delays and their window violations, the client, typed answers."""

from __future__ import annotations

import numpy as np
import pytest

from app.api.schemas import AnalysisReport, ChannelAnalysis, DesignJob, Simulation
from app.client import Client
from app.examples import PAPER_GAINS_H01, PAPER_PLANT
from solver import Channel, Network, PlantFamily, analyze, simulate
from solver.channel import analyze_channel
from solver.channel_delays import weakly_hard_violation_rate

from .conftest import assert_problem, running_client, wait_for
from .test_exports_and_listings import _documented

DELAYS = {"kind": "delays", "max_delay": 1, "n_drop": 2, "min_delay": 0}


@pytest.fixture(scope="module")
def http(module_db):
    with running_client(module_db, workers=1, max_channel_size=20000, sync_time_limit=120.0) as c:
        yield c


@pytest.fixture(scope="module")
def delay_design(http):
    resp = http.post("/v1/designs", json={"plant": PAPER_PLANT, "network": DELAYS}, headers={"Prefer": "wait=120"})
    assert resp.status_code in (201, 202), resp.text
    job = wait_for(http, resp.json()["id"], timeout=300)
    assert job["status"] == "succeeded", job
    return job


@pytest.mark.parametrize("network, pointer, words", [
    ({"kind": "delays", "max_delay": 3, "n_drop": 3}, "/network/max_delay", "n_drop >= 4"),
    ({"kind": "delays", "max_delay": 1, "n_drop": 3, "min_delay": 2}, "/network/min_delay", "min_delay"),
    ({"kind": "weakly_hard", "misses": 5, "window": 3, "n_drop": 3}, "/network/misses", "window"),
    ({"kind": "automaton", "ages": [0, 2], "edges": [[0, 1], [1, 0]]}, "/network/edges/0", "at most 1"),
    ({"kind": "late", "n_drop": 3}, "/network", "kind"),
    ({"kind": "delays", "n_drop": 3}, "/network/delays/max_delay", "Field required"),
])
def test_a_bad_network_is_a_422_naming_the_field(http, network, pointer, words):
    for path, body in (("/v1/designs", {"plant": PAPER_PLANT}),
                       ("/v1/analyses", {"plant": PAPER_PLANT, "gains": PAPER_GAINS_H01}),
                       ("/v1/simulations", {"plant": PAPER_PLANT, "gains": PAPER_GAINS_H01, "x0": [1.0, 1.0]})):
        problem = assert_problem(http.post(path, json={**body, "network": network}), 422, pointer)
        assert words in problem["detail"], (path, problem["detail"])


def test_n_drop_must_agree_with_the_network(http):
    body = {"plant": PAPER_PLANT, "n_drop": 3, "network": DELAYS}
    problem = assert_problem(http.post("/v1/designs", json=body), 422, "/n_drop")
    assert "disagrees" in problem["detail"]
    # three gains given, the network holds two: the gains are named
    body = {"plant": PAPER_PLANT, "gains": PAPER_GAINS_H01, "network": DELAYS}
    assert_problem(http.post("/v1/analyses", json=body), 422, "/gains")


def test_design_on_a_delay_network_matches_the_library(http, delay_design):
    res = delay_design["result"]
    _documented(DesignJob, delay_design, "design job")
    assert res["network"] == DELAYS and res["n_drop"] == 2
    assert res["outcome"] == "stabilized" and res["certificate"]["verified"] is True
    fam = PlantFamily.from_dict(PAPER_PLANT)
    # the gains are certified on the network by the library's own analysis, independently of the design
    rep = analyze(fam, np.array(res["gains"]), network=Network.from_dict(DELAYS))
    assert rep.stable is True
    # the .mat export names the network and carries the node-dependent certificate
    import io

    import scipy.io

    mat = scipy.io.loadmat(io.BytesIO(http.get(f"/v1/designs/{delay_design['id']}/gains.mat").content))
    assert str(mat["network"][0]) == "delays(max_delay=1, n_drop=2)"
    assert mat["P"].shape[0] == mat["P_node"].shape[0] == mat["node_ages"].shape[0]
    net = Network.from_dict(DELAYS)
    np.testing.assert_array_equal(mat["node_ages"].ravel(), net.ages[mat["P_node"].ravel().astype(int) - 1])


def test_analysis_on_a_delay_network_matches_the_library(http, delay_design):
    gains = delay_design["result"]["gains"]
    resp = http.post("/v1/analyses", json={"plant": PAPER_PLANT, "gains": gains, "network": DELAYS})
    assert resp.status_code == 200, resp.text
    data = resp.json()
    _documented(AnalysisReport, data, "analysis")
    fam = PlantFamily.from_dict(PAPER_PLANT)
    ref = analyze(fam, np.array(gains), network=Network.from_dict(DELAYS))
    assert data["stable"] is ref.stable is True and data["network"] == DELAYS
    assert "delays(max_delay=1, n_drop=2)" in data["reason"]
    # the paper's gains on a one-sample-late network: an answer, whatever it is, with its network
    resp = http.post("/v1/analyses", json={"plant": PAPER_PLANT, "gains": PAPER_GAINS_H01,
                                           "network": {"kind": "delays", "max_delay": 1, "n_drop": 3}})
    assert resp.status_code == 200, resp.text
    ref = analyze(fam, np.array(PAPER_GAINS_H01), network=Network.delays(1, 3))
    assert resp.json()["stable"] == ref.stable


def test_simulation_on_a_network_has_admissible_ages(http):
    body = {"plant": PAPER_PLANT, "gains": PAPER_GAINS_H01, "x0": [1.0, -1.0], "steps": 60, "seed": 3,
            "network": {"kind": "weakly_hard", "misses": 2, "window": 5, "n_drop": 3}}
    resp = http.post("/v1/simulations", json=body)
    assert resp.status_code == 200, resp.text
    data = resp.json()
    _documented(Simulation, data, "simulation")
    net = Network.weakly_hard(2, 5, 3)
    assert len(data["ages"]) == 60 and net.admissible(data["ages"])
    fam = PlantFamily.from_dict(PAPER_PLANT)
    ref = simulate(fam, np.array(PAPER_GAINS_H01), x0=[1.0, -1.0], steps=60, seed=3, network=net)
    assert data["ages"] == list(ref.ages)
    np.testing.assert_allclose(data["x"], ref.x if hasattr(ref, "x") else ref.state, rtol=1e-12)


def test_channel_with_delays_and_a_network(http):
    channel = {"kind": "gilbert_elliott", "p_gb": 0.1, "p_bg": 0.3, "loss_good": 0.05, "loss_bad": 0.8,
               "delays": [0.6, 0.3, 0.1]}
    body = {"plant": PAPER_PLANT, "gains": PAPER_GAINS_H01, "channel": channel, "exhausted": "zero",
            "weights": {"Q": [[1, 0], [0, 1]], "R": [[1]]},
            "network": {"kind": "weakly_hard", "misses": 2, "window": 5, "n_drop": 3}}
    resp = http.post("/v1/channels", json=body)
    assert resp.status_code == 200, resp.text
    data = resp.json()
    _documented(ChannelAnalysis, data, "channel")
    fam = PlantFamily.from_dict(PAPER_PLANT)
    ch = Channel.gilbert_elliott(0.1, 0.3, 0.05, 0.8).with_delays([0.6, 0.3, 0.1])
    ref = analyze_channel(fam, np.array(PAPER_GAINS_H01), 3, ch, exhausted="zero", weights=(np.eye(2), np.eye(1)))
    assert data["ms_stable"] is True and data["delays"] == [0.6, 0.3, 0.1]
    assert data["expected_cost"] == pytest.approx(ref.expected_cost, rel=1e-9)
    assert data["burst_rate"] == pytest.approx(ref.burst_rate, rel=1e-12)
    wh = weakly_hard_violation_rate(ch, 2, 5, 3)
    assert data["network_violations"]["rate"] == pytest.approx(wh.rate, rel=1e-12)
    # delays the buffer cannot apply, and delays that do not sum to 1: 422 naming /channel/delays
    for delays in ([0.2, 0.2, 0.2, 0.4], [0.5, 0.4]):
        bad = {**body, "channel": {**channel, "delays": delays}}
        assert_problem(http.post("/v1/channels", json=bad), 422, "/channel/delays")
    # a simulation draws losses from a channel, not delays: refused by name
    sim = {"plant": PAPER_PLANT, "gains": PAPER_GAINS_H01, "x0": [1.0, 1.0], "channel": channel}
    assert_problem(http.post("/v1/simulations", json=sim), 422, "/channel/delays")


def test_openapi_lists_the_network_kinds_and_not_certified(http):
    spec = http.get("/openapi.json").json()
    schemas = spec["components"]["schemas"]
    kinds = {schemas[name]["properties"]["kind"].get("const") for name in
             ("BoundedDropsNetwork", "DelaysNetwork", "WeaklyHardNetwork", "AutomatonNetwork")}
    assert kinds == {"bounded_drops", "delays", "weakly_hard", "automaton"}
    assert "not_certified" in schemas["DesignResult"]["properties"]["outcome"]["enum"]
    for name in ("DesignRequest", "AnalysisRequest", "SimulationRequest", "ChannelRequest"):
        assert "network" in schemas[name]["properties"], name


def test_client_sends_networks(http, delay_design):
    client = Client("http://testserver", http_client=http, poll_interval=0.05)
    fam = PlantFamily.from_dict(PAPER_PLANT)
    gains = np.array(delay_design["result"]["gains"])
    res = client.analyze(fam, gains, network="delays:1,2")
    assert res.stable is True and res.raw["network"] == DELAYS
    run = client.simulate(fam, gains, [1.0, 1.0], network=Network.delays(1, 2), steps=30, seed=5)
    assert run.ages is not None and Network.delays(1, 2).admissible(run.ages.tolist())
    rep = client.analyze_channel(fam, PAPER_GAINS_H01, Channel.bernoulli(0.2).with_delays([0.7, 0.3]),
                                 network={"kind": "bounded_drops", "n_drop": 3})
    ref = analyze_channel(fam, np.array(PAPER_GAINS_H01), 3, Channel.bernoulli(0.2).with_delays([0.7, 0.3]),
                          network=Network.bounded_drops(3))
    assert rep.raw["network_violations"]["rate"] == pytest.approx(ref.network_violations["rate"], rel=1e-12)


def test_a_network_designs_trace_figure_and_c_code_follow_its_network(http, delay_design):
    import io
    import zipfile

    job_id = delay_design["id"]
    resp = http.get(f"/v1/designs/{job_id}/trace?steps=40&seed=4")
    assert resp.status_code == 200, resp.text
    trace = resp.json()
    net = Network.from_dict(DELAYS)
    assert len(trace["ages"]) == 40 and net.admissible(trace["ages"])
    assert all(net.admissible(run["ages"]) for run in trace["per_mode"])
    svg = http.get(f"/v1/designs/{job_id}/trace.svg?steps=40&seed=4")
    assert svg.status_code == 200 and b"age (samples)" in svg.content
    z = zipfile.ZipFile(io.BytesIO(http.get(f"/v1/designs/{job_id}/controller.zip").content))
    header = z.read("ncs_controller.h").decode()
    assert "delays(max_delay=1, n_drop=2)" in header


def test_a_network_design_too_big_is_refused_up_front_naming_the_network(http):
    from solver.compiled import design_size

    net = Network.weakly_hard(5, 12, 7)
    fam = PlantFamily.from_dict(PAPER_PLANT)
    size = design_size("lmi", fam.n_states, fam.n_inputs, fam.n_modes, net.n_drop, network=net)
    assert size.lmi_size > 6000  # the service's default NCS_MAX_LMI_SIZE
    body = {"plant": PAPER_PLANT, "network": net.to_dict()}
    problem = assert_problem(http.post("/v1/designs", json=body), 422, "/network")
    assert str(size.lmi_size) in problem["detail"] and "NCS_MAX_LMI_SIZE" in problem["detail"]


def test_the_network_examples_of_the_openapi_document_run(http):
    from app.examples import CHANNEL_EXAMPLES, DESIGN_EXAMPLES, SIMULATION_EXAMPLES

    resp = http.post("/v1/channels", json=CHANNEL_EXAMPLES["paper_late_packets"]["value"])
    assert resp.status_code == 200 and resp.json()["network_violations"]["rate"] > 0, resp.text
    resp = http.post("/v1/simulations", json=SIMULATION_EXAMPLES["paper_weakly_hard"]["value"])
    assert resp.status_code == 200 and Network.weakly_hard(2, 5, 3).admissible(resp.json()["ages"]), resp.text
    resp = http.post("/v1/designs", json=DESIGN_EXAMPLES["paper_delays"]["value"], headers={"Prefer": "wait=120"})
    job = wait_for(http, resp.json()["id"], timeout=300)
    assert job["status"] == "succeeded" and job["result"]["outcome"] == "stabilized", job


def test_a_huge_network_n_drop_is_refused_before_the_automaton_is_built(http):
    # Network.delays(64, 10**9) would allocate ~20 GB: the service's n_drop limit comes first
    for network, pointer in (({"kind": "delays", "max_delay": 64, "n_drop": 4000}, "/network/n_drop"),
                             ({"kind": "bounded_drops", "n_drop": 10**9}, "/network")):
        for path, body in (("/v1/designs", {"plant": PAPER_PLANT}),
                           ("/v1/channels", {"plant": PAPER_PLANT, "gains": PAPER_GAINS_H01,
                                             "channel": {"kind": "bernoulli", "loss": 0.1}})):
            problem = assert_problem(http.post(path, json={**body, "network": network}), 422, pointer)
            assert "n_drop" in problem["detail"]


def test_cost_design_on_a_delay_network_matches_the_library(http):
    """objective="cost" with a network (docs/design.md §11.3): the job's bracket is the library's, the node
    matrices and the witness walk are documented fields."""
    from solver import design

    body = {"plant": PAPER_PLANT, "network": DELAYS, "objective": "cost", "x0": [1.0, -1.0]}
    resp = http.post("/v1/designs", json=body, headers={"Prefer": "wait=120"})
    assert resp.status_code in (201, 202), resp.text
    job = wait_for(http, resp.json()["id"], timeout=300)
    assert job["status"] == "succeeded", job
    _documented(DesignJob, job, "design job")
    res = job["result"]
    assert res["outcome"] == "stabilized" and res["objective"] == "cost" and res["network"] == DELAYS
    perf = res["performance"]
    direct = design(PlantFamily.from_dict(PAPER_PLANT), network=Network.from_dict(DELAYS), objective="cost",
                    x0=[1.0, -1.0]).performance
    assert perf["verified"] and perf["form"] == "augmented" and perf["walk"]
    assert perf["upper"] == pytest.approx(direct.upper, rel=1e-6)
    assert perf["lower"] == pytest.approx(direct.lower, rel=1e-6)
    nodes = Network.from_dict(DELAYS).nodes
    assert np.array(perf["certificate"]).shape == (nodes, 4, 4)  # one P per node on (x(t), x(t-1))
    # the client's typed bracket (app.client reads the JSON with Performance.from_dict) keeps the network's fields
    from app.client import _performance
    from solver.brackets import NetworkPerformance

    typed = _performance(perf)
    assert isinstance(typed, NetworkPerformance) and typed.form == "augmented" and typed.walk == direct.walk
    assert typed.start_nodes == direct.start_nodes and typed.certificate.shape == (nodes, 4, 4)
    assert (typed.memory, typed.lead) == (direct.memory, direct.lead) == (perf["memory"], perf["lead"])
    assert typed.to_dict() == perf or typed.upper == pytest.approx(direct.upper, rel=1e-6)


@pytest.mark.parametrize("extra, pointer, words", [
    ({"objective": "hinf", "disturbance": [[1.0], [0.0]], "u_max": [1.0]}, "/u_max", "disturbance energy"),
    ({"objective": "hinf", "disturbance": [[1.0], [0.0]], "x0": [1.0, 0.0]}, "/x0", "x = 0"),
    ({"u_max": [1e200], "x0": [1.0, 0.0]}, "/u_max", "between 1e-150 and 1e+150"),
])
def test_network_performance_requests_that_do_not_carry_over_are_422s(http, extra, pointer, words):
    problem = assert_problem(http.post("/v1/designs", json={"plant": PAPER_PLANT, "network": DELAYS, **extra}), 422,
                             pointer)
    assert words in problem["detail"]
