"""Markov channels, burst rates, mean-square stability and expected cost (solver/channel.py, solver/mjls.py).

Every reference here is independent of the code under test: closed forms from the literature or
derived in the docstrings, and seeded Monte Carlo with standard errors.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.optimize import brentq

from solver import Channel, InvalidInput, PlantFamily, analyze, analyze_channel, critical_loss, design, simulate
from solver.channel import compare_schemes, design_for_channel, monte_carlo_cost

SCALAR = PlantFamily(F=[[[2.0]]], G=[[[1.0]]])


# ----------------------------------------------------------------------------- bursts
@pytest.mark.parametrize("p", [0.0, 0.05, 0.3, 0.9])
def test_bernoulli_burst_rate_and_run_lengths_match_closed_forms(p):
    """Bernoulli: a burst of >= N starts at a sample w.p. (1 - p) p^N; run lengths are geometric."""
    ch = Channel.bernoulli(p)
    for N in range(1, 7):
        st = ch.burst_statistics(N, sampling_period=0.01, max_length=12)
        assert st.rate == pytest.approx((1 - p) * p**N, rel=1e-12, abs=1e-300)
        assert st.rate_per_second == pytest.approx((1 - p) * p**N / 0.01, rel=1e-12, abs=1e-300)
        if p > 0:
            assert st.mean_time_between == pytest.approx(1 / ((1 - p) * p**N), rel=1e-12)
            assert st.mean_time_between_seconds == pytest.approx(0.01 / ((1 - p) * p**N), rel=1e-12)
            lengths = np.arange(1, 13)
            np.testing.assert_allclose(st.run_length_pmf, (1 - p) * p ** (lengths - 1), rtol=1e-12, atol=1e-300)
            assert st.run_length_tail == pytest.approx(p**12, rel=1e-9, abs=1e-300)
            assert st.mean_run_length == pytest.approx(1 / (1 - p), rel=1e-12)
        else:
            assert st.mean_time_between == math.inf


def test_classic_gilbert_burst_rate_closed_form():
    """Gilbert (loss 0 in good, 1 in bad): a run >= N starts iff good -> bad, then N - 1 bad stays:
    rate = pi_G p_gb (1 - p_bg)^(N - 1), pi_G = p_bg / (p_gb + p_bg)."""
    p_gb, p_bg = 0.02, 0.25
    ch = Channel.gilbert_elliott(p_gb, p_bg, 0.0, 1.0)
    pi_g = p_bg / (p_gb + p_bg)
    for N in range(1, 10):
        assert ch.burst_rate(N) == pytest.approx(pi_g * p_gb * (1 - p_bg) ** (N - 1), rel=1e-12)
    assert ch.burst_statistics(3).mean_run_length == pytest.approx(1 / p_bg, rel=1e-12)


def _burst_starts(eff: np.ndarray, N: int) -> np.ndarray:
    """Per chain: samples k >= 1 with eff[k-1] and eff[k..k+N-1] all lost (needs k + N <= steps)."""
    lost = ~eff
    steps = eff.shape[1]
    window = np.ones((eff.shape[0], steps - N), dtype=bool)
    for j in range(N):
        window &= lost[:, 1 + j:steps - N + 1 + j]
    return (window & eff[:, :steps - N]).sum(axis=1)


def test_gilbert_elliott_burst_counts_monte_carlo():
    """2 * 10^6 seeded samples (1000 independent stationary chains): counts of burst starts, of lost samples and
    the run-length frequencies within 5 standard errors of the exact values."""
    ch = Channel.gilbert_elliott(0.05, 0.3, loss_good=0.02, loss_bad=0.7)
    chains, steps = 1000, 2000
    states, eff = ch.sample(steps, np.random.default_rng(20240518), size=chains)
    assert eff.shape == (chains, steps) and eff.size >= 10**6
    for N in (1, 2, 3, 4):
        counts = _burst_starts(eff, N)
        mean = counts.mean()
        se = counts.std(ddof=1) / np.sqrt(chains)
        expected = ch.burst_rate(N) * (steps - N)
        assert abs(mean - expected) < 5 * se, (N, mean, expected, se)
    lost = (~eff).sum(axis=1)
    assert abs(lost.mean() - ch.loss_fraction * steps) < 5 * lost.std(ddof=1) / np.sqrt(chains)
    bad = (states == 1).sum(axis=1)
    assert abs(bad.mean() - ch.stationary[1] * steps) < 5 * bad.std(ddof=1) / np.sqrt(chains)
    # Run lengths: every complete run of lost samples (effective before and after it).
    lengths = []
    for row in ~eff:
        edges = np.diff(np.concatenate([[0], row.astype(np.int8), [0]]))
        starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        keep = (starts > 0) & (ends < steps)
        lengths.append(ends[keep] - starts[keep])
    lengths = np.concatenate(lengths)
    pmf = ch.burst_statistics(1, max_length=5).run_length_pmf
    for ell in range(1, 6):
        freq = np.mean(lengths == ell)
        assert abs(freq - pmf[ell - 1]) < 5 * np.sqrt(pmf[ell - 1] * (1 - pmf[ell - 1]) / lengths.size), ell


def test_smallest_n_drop_once_a_year_at_10ms():
    """Bernoulli p: the smallest N with (1 - p) p^N <= target * h, by logarithms."""
    year = 365.25 * 86400
    for p in (0.01, 0.1, 0.3):
        N = Channel.bernoulli(p).smallest_n_drop(1 / year, sampling_period=0.01)
        exact = math.ceil(math.log(0.01 / year / (1 - p)) / math.log(p))
        assert N == exact
    ge = Channel.gilbert_elliott(0.01, 0.3, 0.01, 0.5)
    N = ge.smallest_n_drop(1 / year, sampling_period=0.01)
    assert ge.burst_rate(N) <= 0.01 / year < ge.burst_rate(N - 1)
    assert Channel.gilbert_elliott(0.1, 0.1, 0.0, 1.0).smallest_n_drop(0.0, max_n_drop=50) is None


def test_channel_json_round_trip():
    ge = Channel.combine(Channel.gilbert_elliott(0.1, 0.2, 0.05, 0.9), Channel.bernoulli(0.1))
    back = Channel.from_dict(json.loads(json.dumps(ge.to_dict())))
    np.testing.assert_array_equal(back.transition, ge.transition)
    np.testing.assert_array_equal(back.loss, ge.loss)
    assert back.state_names == ge.state_names and back.burst_rate(3) == ge.burst_rate(3)


def test_combined_links_are_one_bernoulli_chain():
    """Independent Bernoulli sensor and control links: effective w.p. (1 - p_s)(1 - p_c)."""
    both = Channel.combine(Channel.bernoulli(0.1), Channel.bernoulli(0.2))
    one = Channel.bernoulli(1 - 0.9 * 0.8)
    for N in (1, 2, 5):
        assert both.burst_rate(N) == pytest.approx(one.burst_rate(N), rel=1e-12)
    ge = Channel.combine(Channel.gilbert_elliott(0.1, 0.2, 0.0, 1.0), Channel.bernoulli(0.1))
    assert ge.n_states == 2 and ge.loss_fraction == pytest.approx(1 - (0.2 / 0.3) * 0.9, rel=1e-12)


@pytest.mark.parametrize("call, field", [
    (lambda: Channel([[0.5, 0.4], [0.5, 0.5]], [0, 1]), ("transition", 0)),
    (lambda: Channel([[1.0]], [1.5]), ("loss",)),
    (lambda: Channel(np.eye(2), [0.1, 0.2]), ("transition",)),
    (lambda: Channel.gilbert_elliott(0.0, 0.0), ("p_gb",)),
    (lambda: Channel.bernoulli(-0.1), ("loss",)),
    (lambda: Channel.from_dict({"kind": "gilbert_elliott", "p_gb": 0.1}), ("p_bg",)),
    (lambda: Channel.bernoulli(0.1).burst_rate(0), ("n_drop",)),
    (lambda: analyze_channel(SCALAR, [[[-2.0]]], 1, Channel.bernoulli(0.1), exhausted="drop"), ("exhausted",)),
    (lambda: analyze_channel(SCALAR, [[[-2.0]]], 1, "wifi"), ("channel",)),
    (lambda: analyze_channel(SCALAR, [[[-2.0]]], 1, Channel.bernoulli(0.1), plant_transitions=[[0.5]]),
     ("plant_transitions", 0)),
    (lambda: analyze_channel(SCALAR, [[[-2.0]]], 1, Channel.bernoulli(0.1), weights=(-1.0, 1.0)), ("Q",)),
    (lambda: simulate(SCALAR, [[[-2.0]]], 1, [1.0], 10, 0, plant_transitions=[[1.0]]), ("plant_transitions",)),
])
def test_bad_input_names_the_field(call, field):
    with pytest.raises(InvalidInput) as err:
        call()
    assert err.value.field == field


# ----------------------------------------------------------------- mean-square stability
@pytest.mark.parametrize("a", [1.5, 2.0, 3.0])
def test_critical_loss_zero_input_deadbeat_scalar(a):
    """x(k+1) = a x(k) + u(k), u = -a x(k) on an effective sample and 0 on a lost one: with n_drop = 1 and
    exhausted="zero" this is the Bernoulli loop of Sinopoli et al. (2004) / Schenato et al. (Proc. IEEE 2007,
    zero input) / Elia (SCL 2005): E x(k+1)^2 = p a^2 E x(k)^2, mean-square stable iff p a^2 < 1, p_c = 1/a^2."""
    K = [[[-a]]]
    fam = PlantFamily(F=[[[a]]], G=[[[1.0]]])
    pc = critical_loss(fam, K, 1, exhausted="zero")
    assert pc == pytest.approx(1 / a**2, abs=1e-6)
    below = analyze_channel(fam, K, 1, Channel.bernoulli(0.9 / a**2), exhausted="zero")
    above = analyze_channel(fam, K, 1, Channel.bernoulli(1.1 / a**2), exhausted="zero")
    assert below.ms_stable is True and below.upper_certificate.verified and below.ms_radius_upper < 1
    assert above.ms_stable is False and above.lower_certificate.verified and above.ms_radius_lower >= 1
    assert below.ms_radius == pytest.approx(0.9, rel=1e-9) and above.ms_radius == pytest.approx(1.1, rel=1e-9)


def test_critical_loss_hold_deadbeat_scalar_renewal_formula():
    """Same loop with the input held (n_drop = 1, exhausted="hold"): after an effective sample x(i+1) = 0 and,
    while packets are lost, x(i+t) = -x(i) a (a^(t-1) - 1)/(a - 1).  The interval length eta is geometric,
    P(eta) = (1 - p) p^(eta - 1), i.i.d., so x at effective samples is mean-square stable iff
    sum_eta P(eta) (a (a^(eta-1) - 1)/(a - 1))^2 < 1 (a renewal argument; finite iff p a^2 < 1):
    (1 - p) a^2/(a - 1)^2 [p a^2/(1 - p a^2) - 2 p a/(1 - p a) + p/(1 - p)] = 1 at p_c."""
    a = 2.0

    def excess(p):
        return (1 - p) * a**2 / (a - 1) ** 2 * (p * a**2 / (1 - p * a**2) - 2 * p * a / (1 - p * a)
                                                 + p / (1 - p)) - 1

    pc_ref = brentq(excess, 1e-9, 1 / a**2 - 1e-9, xtol=1e-14)
    pc = critical_loss(SCALAR, [[[-a]]], 1, exhausted="hold")
    assert pc == pytest.approx(pc_ref, abs=1e-6)
    assert analyze_channel(SCALAR, [[[-a]]], 1, Channel.bernoulli(pc_ref * 1.1), exhausted="hold").ms_stable is False
    assert analyze_channel(SCALAR, [[[-a]]], 1, Channel.bernoulli(pc_ref * 0.9), exhausted="hold").ms_stable is True


def test_exhaustion_destabilizes_a_loop_certified_under_the_bound():
    """Gains certified by analyze (stable under <= n_drop - 1 losses) on a plant with a = 2: a Bernoulli channel
    breaks the bound, and with the input held the loss runs grow x like a^2 p per sample (held K_N x(i_m) cannot
    stop it): mean-square unstable for p > 1/4; certificates both ways."""
    K = [[[-1.5]], [[-0.5]]]
    assert analyze(SCALAR, K, 2).stable is True
    ok = analyze_channel(SCALAR, K, 2, Channel.bernoulli(0.2), exhausted="hold")
    bad = analyze_channel(SCALAR, K, 2, Channel.bernoulli(0.3), exhausted="hold")
    assert ok.ms_stable is True and ok.upper_certificate.verified
    assert bad.ms_stable is False and bad.lower_certificate.verified and bad.lower_certificate.mu >= 1
    assert critical_loss(SCALAR, K, 2, exhausted="hold") == pytest.approx(0.25, abs=1e-6)


def test_exhaustion_never_destabilizes_the_paper_motor():
    """The paper's motor is open-loop stable: zero input or a held input on long loss runs cannot destabilize
    it; mean-square stable for every loss probability, with a certificate at p = 0.95."""
    fam = PlantFamily.paper_example(0.1)
    K = design(fam, 3).gains
    for exhausted in ("hold", "zero"):
        assert critical_loss(fam, K, 3, exhausted=exhausted) == 1.0
        rep = analyze_channel(fam, K, 3, Channel.bernoulli(0.95), exhausted=exhausted)
        assert rep.ms_stable is True and rep.ms_radius_upper < 1


def test_radius_bounds_bracket_the_estimate():
    fam = PlantFamily(F=[[[1.2, 0.3], [0.0, 0.9]], [[1.1, 0.0], [0.2, 0.7]]], G=[[[1.0], [0.5]], [[0.8], [1.0]]])
    K = design(fam, 3).gains
    ch = Channel.gilbert_elliott(0.1, 0.3, 0.05, 0.8)
    for exhausted in ("hold", "zero"):
        rep = analyze_channel(fam, K, 3, ch, exhausted=exhausted, plant_transitions=[[0.9, 0.1], [0.2, 0.8]])
        assert rep.ms_stable is not None
        if rep.ms_radius_upper is not None:
            assert rep.ms_radius <= rep.ms_radius_upper
        if rep.ms_radius_lower is not None:
            assert rep.ms_radius_lower <= rep.ms_radius
        json.dumps(rep.to_dict())


def test_arbitrary_plant_switching_lmi_is_consistent_with_markov_chains():
    """The arbitrary-switching certificate and worst-case cost bound cover every plant chain; a constant unstable
    mode refutes stability."""
    fam = PlantFamily(F=[[[1.2]], [[0.9]]], G=[[[1.0]], [[0.5]]])
    K = design(fam, 3).gains
    ch = Channel.gilbert_elliott(0.1, 0.3, 0.05, 0.6)
    worst = analyze_channel(fam, K, 3, ch, plant_transitions="arbitrary", weights=(1.0, 1.0))
    assert worst.ms_stable is True and worst.upper_certificate.verified
    assert worst.expected_cost_upper is not None
    for Pi in (None, [[0.5, 0.5], [0.5, 0.5]], [[0.0, 1.0], [1.0, 0.0]]):
        rep = analyze_channel(fam, K, 3, ch, plant_transitions=Pi, weights=(1.0, 1.0))
        assert rep.ms_stable is True and rep.ms_radius <= worst.ms_radius_upper + 1e-12
        assert rep.expected_cost <= worst.expected_cost_upper
    bad = analyze_channel(SCALAR, [[[-1.5]], [[-0.5]]], 2, Channel.bernoulli(0.4), plant_transitions="arbitrary")
    assert bad.ms_stable is False


# --------------------------------------------------------------------------- expected cost
def test_expected_cost_scalar_closed_form():
    """n_drop = 1, zero input on loss, u = k x on effective samples, sample 0 effective, E x0^2 = 1:
    E x(j)^2 = (a + k)^2 c^(j-1), c = (1 - p)(a + k)^2 + p a^2, so
    J = 1 + k^2 + (a + k)^2 (1 + (1 - p) k^2) / (1 - c); with noise W the stationary E x^2 = W/(1 - c) and the
    cost per sample is W (1 + (1 - p) k^2)/(1 - c)."""
    a, k, p, W = 1.3, -0.9, 0.3, 0.04
    fam = PlantFamily(F=[[[a]]], G=[[[1.0]]])
    c = (1 - p) * (a + k) ** 2 + p * a**2
    J = 1 + k**2 + (a + k) ** 2 * (1 + (1 - p) * k**2) / (1 - c)
    rep = analyze_channel(fam, [[[k]]], 1, Channel.bernoulli(p), exhausted="zero", weights=(1.0, 1.0), noise=W)
    assert rep.expected_cost == pytest.approx(J, rel=1e-10)
    assert rep.expected_cost_lower <= J <= rep.expected_cost_upper
    assert rep.expected_cost_upper - rep.expected_cost_lower < 1e-4 * J
    assert rep.stationary_cost == pytest.approx(W * (1 + (1 - p) * k**2) / (1 - c), rel=1e-9)


def test_expected_cost_matches_monte_carlo():
    """Gilbert-Elliott channel, Markov plant jumps, both exhaustion policies: the exact cost lies in the
    99% confidence interval of 20000 seeded runs (horizon 300, radius^300 < 1e-60)."""
    fam = PlantFamily(F=[[[1.2]], [[1.1]]], G=[[[1.0]], [[0.8]]])
    K = design(fam, 2, decay_rate=None).gains  # the plain design: its slow loop makes a long horizon matter
    ch = Channel.gilbert_elliott(0.1, 0.4, 0.1, 0.7)
    Pi = [[0.9, 0.1], [0.2, 0.8]]
    for exhausted in ("hold", "zero"):
        rep = analyze_channel(fam, K, 2, ch, exhausted=exhausted, plant_transitions=Pi, weights=(1.0, 1.0))
        assert rep.ms_radius**300 < 1e-60
        mc = monte_carlo_cost(fam, K, 2, ch, (1.0, 1.0), exhausted=exhausted, plant_transitions=Pi, runs=20000,
                              horizon=300, seed=7)
        assert mc.ci_low <= rep.expected_cost <= mc.ci_high, (exhausted, rep.expected_cost, mc)
        assert rep.expected_cost_lower <= rep.expected_cost <= rep.expected_cost_upper


def test_compare_schemes_and_design_for_channel():
    fam = PlantFamily(F=[[[1.2]], [[1.1]]], G=[[[1.0]], [[0.8]]])
    ch = Channel.gilbert_elliott(0.1, 0.4, 0.1, 0.7)
    rows = compare_schemes(fam, ch, [1, 2], weights=(1.0, 1.0), exhausted="zero")
    assert [(r["scheme"], r["n_drop"]) for r in rows] == [(s, N) for s in ("predictive", "hold", "zero")
                                                          for N in (1, 2)]
    assert all(r["ms_stable"] is True and r["expected_cost"] > 0 for r in rows)
    out = design_for_channel(fam, ch, 1e-3, per="sample", weights=(1.0, 1.0))
    assert ch.burst_rate(out.n_drop) <= 1e-3 < ch.burst_rate(out.n_drop - 1)
    assert out.design.outcome == "stabilized" and out.analysis.ms_stable is True
    json.dumps(out.to_dict())


# ------------------------------------------------------------------------------ simulation
def test_simulate_on_a_channel_runs_past_the_bound():
    fam = PlantFamily(F=[[[1.2]], [[0.9]]], G=[[[1.0]], [[0.5]]])
    K = design(fam, 2).gains
    ch = Channel.gilbert_elliott(0.2, 0.2, 0.1, 0.9)
    Pi = [[0.7, 0.3], [0.4, 0.6]]
    runs = {ex: simulate(fam, K, 2, [1.0], 400, 11, channel=ch, exhausted=ex, plant_transitions=Pi)
            for ex in ("hold", "zero")}
    again = simulate(fam, K, 2, [1.0], 400, 11, channel=ch, exhausted="hold", plant_transitions=Pi)
    assert json.dumps(again.to_dict()) == json.dumps(runs["hold"].to_dict())
    for ex, tr in runs.items():
        assert tr.loss_model == "channel" and tr.effective[0]
        assert tr.buffer_index.max() > 2  # runs longer than the bound happen
        assert set(np.unique(tr.mode)) == {0, 1}
        np.testing.assert_array_equal(tr.effective, tr.sensor_arrived)
        for k in np.flatnonzero(tr.buffer_index > 2):
            i_m = tr.interval_start[tr.interval_start <= k][-1]
            expected = K[1] @ tr.state[i_m] if ex == "hold" else np.zeros(1)
            np.testing.assert_allclose(tr.input[k], expected, rtol=1e-15)
    # the channel draws do not depend on the exhaustion policy
    np.testing.assert_array_equal(runs["hold"].effective, runs["zero"].effective)


def test_channel_figure_renders():
    from solver.channel import loss_sweep
    from solver.plotting import channel_figure, render

    sweep = loss_sweep(SCALAR, [[[-1.5]], [[-0.5]]], 2, [0.1, 0.2, 0.3], weights=(1.0, 1.0))
    assert [r["ms_stable"] for r in sweep if r["exhausted"] == "hold"] == [True, True, False]
    svg = render(channel_figure(Channel.gilbert_elliott(0.05, 0.3, 0.01, 0.8), range(1, 8), 0.1, sweep), "svg")
    assert b"per hour" in svg and b"exhausted = zero" in svg
    assert svg == render(channel_figure(Channel.gilbert_elliott(0.05, 0.3, 0.01, 0.8), range(1, 8), 0.1, sweep),
                         "svg")


# ------------------------------------------------------------------------- design for a channel
def test_design_channel_recovers_the_modified_riccati_optimum():
    """TCP-like optimal control with i.i.d. losses (Schenato et al., Proc. IEEE 2007, Sec. IV; Imer, Yuksel,
    Basar 2006): x(k+1) = a x + u applied w.p. 1 - p (zero otherwise), cost sum x^2 + u^2; the optimal gain is
    k = -a P / (1 + P) with P = 1 + a^2 P - (1 - p) a^2 P^2 / (1 + P).  With n_drop = 1 and exhausted="zero" it is
    our loop; sample 0 effective gives J = 1 + k^2 + (a + k)^2 (1 + (1 - p) k^2)/(1 - c) (see above)."""
    a, p = 1.3, 0.3
    P = 1.0
    for _ in range(5000):
        P = 1 + a * a * P - (1 - p) * (a * P) ** 2 / (1 + P)
    k = -a * P / (1 + P)
    c = (1 - p) * (a + k) ** 2 + p * a**2
    J = 1 + k**2 + (a + k) ** 2 * (1 + (1 - p) * k**2) / (1 - c)
    fam = PlantFamily(F=[[[a]]], G=[[[1.0]]])
    from solver.channel import design_channel

    res = design_channel(fam, 1, Channel.bernoulli(p), exhausted="zero", weights=(1.0, 1.0))
    assert res.outcome == "stabilized" and res.analysis.ms_stable is True
    assert res.gains[0, 0, 0] == pytest.approx(k, abs=1e-4)
    assert res.analysis.expected_cost == pytest.approx(J, rel=1e-6)
    assert res.analysis.expected_cost >= J * (1 - 1e-12)  # nothing beats the optimum


def test_design_channel_beats_the_worst_case_design_on_its_channel():
    """The paper's motor over a Gilbert-Elliott link: the channel design's exact expected cost is below that of
    the worst-case (Theorem 1) design, and below its own SDP bound."""
    from solver.channel import design_channel

    fam = PlantFamily.paper_example(0.1)
    link = Channel.gilbert_elliott(0.05, 0.3, 0.01, 0.8)
    W = (np.eye(2), np.eye(1))
    res = design_channel(fam, 3, link, exhausted="zero", weights=W)
    assert res.outcome == "stabilized" and res.analysis.upper_certificate.verified
    worst_case = analyze_channel(fam, design(fam, 3).gains, 3, link, exhausted="zero", weights=W)
    assert res.analysis.expected_cost < 0.5 * worst_case.expected_cost
    assert res.analysis.expected_cost_upper <= res.sdp_bound * (1 + 1e-6)
    json.dumps(res.to_dict())


def test_simulate_on_a_channel_has_the_analyzed_expected_cost():
    """simulate's own loop (buffer ages, exhaustion, channel and plant draws) against analyze_channel: the mean cost
    of 1000 seeded runs of 80 samples (x0 ~ N(0, 1)) lies within 4 standard errors of the exact expected cost."""
    fam = PlantFamily(F=[[[1.2]], [[1.05]]], G=[[[1.0]], [[0.7]]])
    K = np.array([[[-0.9]], [[-0.4]]])
    ch = Channel.gilbert_elliott(0.15, 0.35, 0.05, 0.75)
    Pi = [[0.8, 0.2], [0.3, 0.7]]
    rng = np.random.default_rng(99)
    for exhausted in ("hold", "zero"):
        rep = analyze_channel(fam, K, 2, ch, exhausted=exhausted, plant_transitions=Pi, weights=(1.0, 1.0))
        assert rep.ms_stable is True and rep.ms_radius**80 < 1e-6  # the truncated tail is far below one standard error
        costs = []
        for seed in range(1000):
            tr = simulate(fam, K, 2, [rng.standard_normal()], 80, seed, channel=ch, exhausted=exhausted,
                          plant_transitions=Pi)
            costs.append(float(np.sum(tr.state[:-1] ** 2) + np.sum(tr.input**2)))
        se = np.std(costs, ddof=1) / np.sqrt(len(costs))
        assert abs(np.mean(costs) - rep.expected_cost) < 4 * se, (exhausted, np.mean(costs), rep.expected_cost, se)


def test_open_loop_growth_with_a_stable_direction_is_proven():
    """No input (K = 0), F = [[1.1, 0.3], [0.2, 0.6]] (eigenvalues 1.2 and 0.5): the second moment grows like
    1.2^2 = 1.44 per sample along the unstable eigenvector while the direction of the stable left eigenvector
    shrinks in every mode, so no positive definite moment can grow in every direction (and float64 cannot keep the
    rank-one growth exact); the verdict comes from an exact cycle (probability times radius squared >= 1, decided
    in integer arithmetic)."""
    fam = PlantFamily(F=[[[1.1, 0.3], [0.2, 0.6]]], G=[[[0.0], [1.0]]])
    for exhausted in ("hold", "zero"):
        rep = analyze_channel(fam, np.zeros((2, 1, 2)), 2, Channel.bernoulli(0.3), exhausted=exhausted)
        assert rep.ms_radius == pytest.approx(1.44, rel=1e-9)
        assert rep.ms_stable is False and rep.lower_certificate.verified
        assert rep.lower_certificate.kind == "cycle"
        assert 1.0 <= rep.ms_radius_lower <= 1.44
        json.dumps(rep.to_dict())


def test_random_loops_never_crash_and_proofs_never_contradict():
    """Seeded random loops (open loop, huge entries, certain losses, periodic channels, every plant chain kind):
    bad input is InvalidInput, every report is JSON, and a proven lower bound never exceeds a proven upper bound."""
    import warnings

    rng = np.random.default_rng(12)
    channels = [Channel.bernoulli(0.0), Channel.bernoulli(0.7), Channel.bernoulli(1.0),
                Channel.gilbert_elliott(0.3, 0.2, 0.0, 1.0), Channel([[0, 1], [1, 0]], [1.0, 0.0])]
    verdicts = set()
    for t in range(40):
        n, m, r, N = (int(v) for v in (rng.integers(1, 4), rng.integers(1, 3), rng.integers(1, 3), rng.integers(1, 4)))
        scale = 10.0 ** int(rng.integers(-3, 120)) if t % 9 == 0 else 1.0
        fam = PlantFamily(F=rng.standard_normal((r, n, n)) * scale, G=rng.standard_normal((r, n, m)))
        K = rng.standard_normal((N, m, n)) * (0.0 if t % 4 == 1 else 0.5)
        plants = [None, "arbitrary", [[1.0 / r] * r] * r][t % 3]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rep = analyze_channel(fam, K, N, channels[t % 5], exhausted=("hold", "zero")[t % 2],
                                  weights=(np.eye(n), np.eye(m)), plant_transitions=plants)
        json.dumps(rep.to_dict())
        verdicts.add(rep.ms_stable)
        if rep.ms_radius_lower is not None and rep.ms_radius_upper is not None:
            assert rep.ms_radius_lower <= rep.ms_radius_upper
        if rep.ms_stable is True and rep.expected_cost is not None:
            assert rep.expected_cost_lower <= rep.expected_cost <= rep.expected_cost_upper
    assert {True, False} <= verdicts


# ---------------------------------------------------------------------------- dead links (issue 33, item 8)
@pytest.mark.parametrize("link", [Channel.bernoulli(1.0), Channel.gilbert_elliott(0.1, 0.0),
                                  Channel.gilbert_elliott(0.1, 0.0, loss_good=0.0, loss_bad=1.0),
                                  Channel([[0.5, 0.5], [0.0, 1.0]], [0.0, 1.0])],
                         ids=["bernoulli-1", "ge-absorbing", "ge-absorbing-explicit", "markov-absorbing"])
def test_a_link_that_never_delivers_is_reported_as_such(link):
    """Runs were counted from a delivered sample, so a dead link reported burst rate 0, an infinite mean time
    between bursts and smallest_n_drop 1: it looked like the best link there is."""
    # Reference: the stationary probability of delivering, from the chain's own pi (brute-force power iteration).
    pi = np.full(link.n_states, 1.0 / link.n_states)
    for _ in range(20000):
        pi = pi @ link.transition
    assert float(pi @ (1.0 - link.loss)) < 1e-9
    assert link.never_delivers
    b = link.burst_statistics(3, sampling_period=0.01)
    assert b.never_delivers and b.rate == 1.0 and b.mean_time_between == 1.0 and b.run_length_tail == 1.0
    assert b.to_dict()["never_delivers"] is True and b.to_dict()["mean_time_between"] == 1.0
    assert link.smallest_n_drop(1e-6) is None
    fam = PlantFamily.paper_example()
    with pytest.raises(InvalidInput, match="never delivers") as err:
        design_for_channel(fam, link, 1e-3, per="sample")
    assert err.value.field == ("channel",)
    rep = analyze_channel(fam, np.zeros((3, 1, 2)), 3, link)
    assert rep.reason.startswith("the channel never delivers"), rep.reason


def test_a_link_that_delivers_is_not_called_dead():
    for link in (Channel.bernoulli(0.999), Channel.gilbert_elliott(0.1, 0.001)):
        assert not link.never_delivers and not link.burst_statistics(3).never_delivers
        assert link.burst_statistics(3).rate > 0
