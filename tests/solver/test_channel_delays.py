"""Channels with per-packet delays (solver/channel_delays.py): the jump linear system with late packets,
the buffer's exhaustion rate and weakly-hard window violations.

References are independent of the code under test: today's delay-free analysis (a delay pmf at 0 must
give the same numbers), a binomial closed form, and seeded Monte Carlo of the buffer stepped sample by
sample (newest stamp wins) with confidence intervals.
"""

from __future__ import annotations

import json
from math import comb

import numpy as np
import pytest

from solver import Channel, InvalidInput, PlantFamily, analyze_channel, design
from solver.channel import monte_carlo_cost
from solver.channel_delays import (DelayedChannel, ages_from_arrivals, exhaustion_rate, monte_carlo_violations,
                                   network_violations, weakly_hard_violation_rate)
from tests.solver.paper_data import EQ20_F, EQ20_G, EQ23_GAINS

PAPER = PlantFamily(F=EQ20_F, G=EQ20_G, sampling_period=0.1)
TWO = PlantFamily(F=[[[1.2]], [[1.1]]], G=[[[1.0]], [[0.8]]])


def _buffer_ages(delay: np.ndarray) -> np.ndarray:
    """The actuator buffer stepped sample by sample: packets land at s + delay, the newest stamp wins."""
    runs, steps = delay.shape
    out = np.zeros((runs, steps), dtype=np.int64)
    for r in range(runs):
        landing = {}
        for s in range(steps):
            if delay[r, s] >= 0:
                landing.setdefault(s + delay[r, s], []).append(s)
        stamp = 0
        for t in range(steps):
            for s in landing.get(t, []):
                stamp = max(stamp, s)
            out[r, t] = t - stamp
    return out


def test_buffer_ages_by_hand_and_by_stepping():
    # packets: 0 fresh, 1 lost, 2 late by 2 (lands at 4), 3 late by 1 (lands at 4), 4 lost, 5 fresh
    delay = np.array([[0, -1, 2, 1, -1, 0]])
    assert ages_from_arrivals(delay).tolist() == [[0, 1, 2, 3, 1, 0]]
    rng = np.random.default_rng(5)
    ch = Channel.gilbert_elliott(0.2, 0.3, 0.1, 0.8).with_delays([0.3, 0.4, 0.3])
    _, _, d = ch.sample_arrivals(60, rng, size=40)
    d[:, 0] = np.maximum(d[:, 0], 0)
    np.testing.assert_array_equal(ages_from_arrivals(d), _buffer_ages(d))


@pytest.mark.parametrize("exhausted", ["hold", "zero"])
def test_delays_at_zero_reproduce_todays_numbers(exhausted):
    """A delay pmf concentrated at 0 is today's channel: same modes, radius, verdict, cost and burst rate."""
    ge = Channel.gilbert_elliott(0.1, 0.3, 0.05, 0.8)
    Pi = [[0.8, 0.1, 0.1], [0.1, 0.8, 0.1], [0.1, 0.1, 0.8]]
    W = (np.eye(2), 1.0)
    a = analyze_channel(PAPER, EQ23_GAINS, 3, ge, exhausted=exhausted, plant_transitions=Pi, weights=W, noise=0.01 * np.eye(2))
    b = analyze_channel(PAPER, EQ23_GAINS, 3, ge.with_delays([1.0, 0.0]), exhausted=exhausted, plant_transitions=Pi,
                        weights=W, noise=0.01 * np.eye(2))
    assert a.ms_stable is True and b.ms_stable is True and a.n_modes == b.n_modes
    for f in ("ms_radius", "expected_cost", "stationary_cost", "burst_rate"):
        assert getattr(b, f) == pytest.approx(getattr(a, f), rel=1e-9), f
    assert b.expected_cost_lower <= a.expected_cost <= b.expected_cost_upper
    # and an unstable loop stays unstable, with the same radius
    fam = PlantFamily(F=[[[2.0]]], G=[[[1.0]]])
    u1 = analyze_channel(fam, [[[-2.0]]], 1, Channel.bernoulli(0.3), exhausted=exhausted)
    u2 = analyze_channel(fam, [[[-2.0]]], 1, Channel.bernoulli(0.3).with_delays([1.0]), exhausted=exhausted)
    assert u1.ms_stable is False and u2.ms_stable is False
    assert u2.ms_radius == pytest.approx(u1.ms_radius, rel=1e-9)


@pytest.mark.parametrize("exhausted", ["hold", "zero"])
def test_expected_cost_with_delays_matches_monte_carlo(exhausted):
    """Late and reordered packets on a Gilbert-Elliott chain with Markov plant jumps: the exact cost lies in
    the 99% confidence interval of 20000 seeded runs of the buffer (horizon 250, radius^250 negligible)."""
    K = design(TWO, 3, decay_rate=None).gains
    ch = Channel.gilbert_elliott(0.1, 0.4, 0.1, 0.6).with_delays([0.5, 0.3, 0.2])
    Pi = [[0.9, 0.1], [0.2, 0.8]]
    rep = analyze_channel(TWO, K, 3, ch, exhausted=exhausted, plant_transitions=Pi, weights=(1.0, 1.0))
    assert rep.ms_stable is True and rep.ms_radius**250 < 1e-15
    mc = monte_carlo_cost(TWO, K, 3, ch, (1.0, 1.0), exhausted=exhausted, plant_transitions=Pi, runs=20000,
                          horizon=250, seed=11)
    assert mc.ci_low <= rep.expected_cost <= mc.ci_high, (rep.expected_cost, mc)
    assert rep.expected_cost_lower <= rep.expected_cost <= rep.expected_cost_upper
    # the delays matter: the same chain without them costs measurably less
    plain = analyze_channel(TWO, K, 3, Channel.gilbert_elliott(0.1, 0.4, 0.1, 0.6), exhausted=exhausted,
                            plant_transitions=Pi, weights=(1.0, 1.0))
    assert plain.expected_cost_upper < rep.expected_cost_lower
    assert rep.to_dict()["delays"] == [0.5, 0.3, 0.2]


def test_delays_can_destabilize_in_mean_square():
    """A loop that is mean-square stable with on-time packets is proven unstable when half of them come one
    sample late: the design's later gains are ~0, so a late packet leaves the plant (a = 1.5) open loop and
    the radius is 0.2 a^2 + 0.8 * 0.5 a^2 = 1.35 (every sample without a fresh packet multiplies x by a)."""
    fam = PlantFamily(F=[[[1.5]]], G=[[[1.0]]])
    K = design(fam, 3, decay_rate=None).gains
    on_time = analyze_channel(fam, K, 3, Channel.bernoulli(0.2), exhausted="zero")
    late = analyze_channel(fam, K, 3, Channel.bernoulli(0.2).with_delays([0.5, 0.5]), exhausted="zero")
    assert on_time.ms_stable is True
    assert late.ms_stable is False and late.ms_radius_lower >= 1


def test_exhaustion_rate_matches_burst_rate_and_monte_carlo():
    ge = Channel.gilbert_elliott(0.05, 0.3, 0.02, 0.7)
    for N in (1, 2, 3, 4):
        assert exhaustion_rate(ge.with_delays([1.0]), N) == pytest.approx(ge.burst_rate(N), rel=1e-9)
    ch = ge.with_delays([0.4, 0.4, 0.2])
    N = 3
    rate = exhaustion_rate(ch, N)
    rng = np.random.default_rng(9)
    _, _, d = ch.sample_arrivals(3000, rng, size=600)
    ages = ages_from_arrivals(d)[:, 300:]
    starts = ((ages[:, 1:] == N) & (ages[:, :-1] == N - 1)).mean(axis=1)
    se = starts.std(ddof=1) / np.sqrt(starts.size)
    assert abs(starts.mean() - rate) < 5 * se, (starts.mean(), rate, se)


@pytest.mark.parametrize("p,m,K", [(0.1, 1, 4), (0.3, 2, 5), (0.5, 3, 6)])
def test_weakly_hard_rate_bernoulli_closed_form(p, m, K):
    """Independent losses, no delays: a window of K breaks 'at most m' w.p. P(Binomial(K, p) > m)."""
    exact = sum(comb(K, j) * p**j * (1 - p) ** (K - j) for j in range(m + 1, K + 1))
    res = weakly_hard_violation_rate(Channel.bernoulli(p), m, K)
    assert res.rate == pytest.approx(exact, rel=1e-9)
    assert res.miss_fraction == pytest.approx(p, rel=1e-9)


def test_weakly_hard_rate_with_delays_matches_monte_carlo():
    ch = Channel.gilbert_elliott(0.1, 0.3, 0.05, 0.8).with_delays([0.6, 0.3, 0.1])
    for m, K, N in ((2, 5, 3), (1, 3, None)):
        res = weakly_hard_violation_rate(ch, m, K, n_drop=N, sampling_period=0.01)
        mean, se = monte_carlo_violations(ch, m, K, N, runs=800, steps=1500, seed=4)
        assert abs(mean - res.rate) < 5 * se, (m, K, mean, res.rate, se)
        assert res.rate_per_second == pytest.approx(res.rate / 0.01)


def test_network_violations_for_delay_and_drop_networks_match_monte_carlo():
    ch = Channel.bernoulli(0.2).with_delays([0.5, 0.3, 0.2])
    rng = np.random.default_rng(21)
    _, _, d = ch.sample_arrivals(2000, rng, size=500)
    ages = ages_from_arrivals(d)
    for spec in ({"kind": "delays", "max_delay": 1, "n_drop": 3, "min_delay": 0},
                 {"kind": "bounded_drops", "n_drop": 4}):
        lo, hi = spec.get("min_delay", 0), spec.get("max_delay", 0)
        prev, cur = ages[:, 200:-1], ages[:, 201:]
        late = cur < prev + 1
        bad = (cur >= spec["n_drop"]) | (late & ((cur < lo) | (cur > hi)))
        per_run = bad.mean(axis=1)
        rate = network_violations(ch, spec)["rate"]
        assert abs(per_run.mean() - rate) < 5 * per_run.std(ddof=1) / np.sqrt(per_run.size), (spec, rate)
    rep = analyze_channel(TWO, design(TWO, 3, decay_rate=None).gains, 3, ch,
                          network={"kind": "weakly_hard", "misses": 2, "window": 5, "n_drop": 3})
    assert rep.to_dict()["network_violations"]["rate"] == pytest.approx(
        weakly_hard_violation_rate(ch, 2, 5, 3).rate)


def test_delayed_channel_json_round_trip():
    ch = Channel.gilbert_elliott(0.1, 0.2, 0.05, 0.9).with_delays([0.7, 0.2, 0.1])
    back = Channel.from_dict(json.loads(json.dumps(ch.to_dict())))
    assert isinstance(back, DelayedChannel) and back.max_delay == 2
    np.testing.assert_array_equal(back.delays, ch.delays)
    np.testing.assert_array_equal(back.transition, ch.transition)


@pytest.mark.parametrize("make,field", [
    (lambda: Channel.bernoulli(0.1).with_delays([0.5, 0.4]), ("delays",)),
    (lambda: Channel.bernoulli(0.1).with_delays([1.2, -0.2]), ("delays",)),
    (lambda: Channel.bernoulli(0.1).with_delays([]), ("delays",)),
    (lambda: analyze_channel(TWO, np.zeros((2, 1, 1)), 2, Channel.bernoulli(0.1).with_delays([0.5, 0.0, 0.5])),
     ("channel", "delays")),
    (lambda: weakly_hard_violation_rate(Channel.bernoulli(0.1), 3, 3), ("misses",)),
    (lambda: network_violations(Channel.bernoulli(0.1), {"kind": "wifi"}), ("network", "kind")),
])
def test_bad_input_names_the_field(make, field):
    with pytest.raises(InvalidInput) as err:
        make()
    assert err.value.field == field


def test_readme_network_example_prints_what_its_comments_say(capsys):
    """The README's network example: every printed line is the one its `# ...` comment shows."""
    import pathlib
    import re

    text = (pathlib.Path(__file__).resolve().parents[2] / "README.md").read_text()
    section = text[text.index("### Networks: delays and weakly-hard patterns"):]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    exec(compile(code, "README.md", "exec"), {"__name__": "__main__"})
    printed = capsys.readouterr().out.splitlines()
    expected = [line.split("#", 1)[1].strip() for line in code.splitlines() if line.startswith("print(")]
    assert printed == expected


def test_trace_figure_draws_the_ages_of_a_network_run():
    from solver import Network, simulate
    from solver.plotting import render, trace_figure

    net = Network.delays(1, 2)
    tr = simulate(TWO, design(TWO, 2, decay_rate=None).gains, x0=[1.0], steps=20, seed=2, network=net)
    fig = trace_figure([tr], ["delays"], family=TWO)
    labels = [ax.get_ylabel() for ax in fig.axes]
    assert "age (samples)" in labels
    ages_ax = fig.axes[labels.index("age (samples)")]
    np.testing.assert_array_equal(ages_ax.patches[0].get_data().values, np.asarray(tr.ages, dtype=float)[:20])
    assert render(fig, "svg").startswith(b"<?xml")
