"""simulate(..., network=...) and simulate(..., arrivals=...) against the automaton and the generated C buffer."""

import numpy as np
import pytest

from solver import InvalidInput, Network, PlantFamily, export_c, simulate

from .paper_data import EQ23_GAINS
from .test_codegen import CBuffer, assert_inputs_agree, build

PAPER = PlantFamily.paper_example(0.1)


@pytest.mark.parametrize("net", [Network.delays(2, 3), Network.weakly_hard(2, 5, 3), Network.delays(1, 3, 1),
                                 Network.delays(1, 3) & Network.weakly_hard(1, 3, 3)])
def test_drawn_ages_are_admissible_and_seeded(net):
    tr = simulate(PAPER, EQ23_GAINS, x0=[1.0, -2.0], steps=300, seed=4, network=net)
    assert net.admissible(tr.ages) and tr.ages.shape == (300,)
    again = simulate(PAPER, EQ23_GAINS, x0=[1.0, -2.0], steps=300, seed=4, network=net)
    np.testing.assert_array_equal(again.ages, tr.ages)
    np.testing.assert_array_equal(again.state, tr.state)
    # every successor is drawn: more than one age value occurs when the network allows it
    assert len(set(tr.ages.tolist())) == len(set(net.ages.tolist()))
    # the loop itself, stepped here from the ages: u(t) = K_{d+1} x(t - d), x before 0 is x0
    for t in range(300):
        d = tr.ages[t]
        xs = tr.state[max(t - d, 0)]
        assert_inputs_agree(tr.input[t], EQ23_GAINS[d] @ xs)
    d = tr.to_dict()
    assert d["ages"] == tr.ages.tolist() and d["network"] == net.to_dict()


def test_paper_network_has_ages_too():
    tr = simulate(PAPER, EQ23_GAINS, 3, x0=[1.0, -2.0], steps=200, seed=1)
    np.testing.assert_array_equal(tr.ages, tr.buffer_index - 1)
    assert Network.bounded_drops(3).admissible(tr.ages)
    same = simulate(PAPER, EQ23_GAINS, x0=[1.0, -2.0], steps=200, seed=1, network=Network.bounded_drops(3))
    np.testing.assert_array_equal(same.state, tr.state)


def random_deliveries(rng, steps, max_delay, loss=0.3, duplicate=0.15):
    """Packets lost, delayed up to max_delay (so reordered) or duplicated, in a shuffled list."""
    arrivals = []
    for k in range(steps):
        if rng.random() < loss:
            continue
        for _ in range(2 if rng.random() < duplicate else 1):
            arrivals.append((k, k + int(rng.integers(0, max_delay + 1))))
    rng.shuffle(arrivals)
    return arrivals


@pytest.mark.parametrize("exhausted", ["hold", "zero"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_c_buffer_under_delays_and_reordering_matches_simulate(tmp_path, exhausted, seed):
    rng = np.random.default_rng(seed)
    steps = 120
    arrivals = random_deliveries(rng, steps, max_delay=4)
    tr = simulate(PAPER, EQ23_GAINS, n_drop=3, x0=[-3.0, 2.0], steps=steps, seed=seed, arrivals=arrivals,
                  exhausted=exhausted)
    c = CBuffer(build(tmp_path, export_c(EQ23_GAINS, 3, exhausted=exhausted)), "ncs", 1, 3)
    x = tr.state[0]
    late = reordered = 0
    newest = -1
    for k in range(steps):
        arriving = [a for a in arrivals if a[1] == k]  # in the list's (shuffled) order
        for stamp, _ in arriving:
            c.receive(c.packet(tr.state[stamp]), stamp)
            late += stamp < k
            reordered += stamp < newest
            newest = max(newest, stamp)
        u = c.output()
        assert_inputs_agree(u, tr.input[k])
        x = PAPER.F[tr.mode[k]] @ x + PAPER.G[tr.mode[k]] @ u
        np.testing.assert_allclose(x, tr.state[k + 1], rtol=1e-10, atol=1e-12)
    assert late > 0 and reordered > 0
    # ages from the definition: newest stamp delivered so far
    for k in range(steps):
        got = [s for s, a in arrivals if a <= k]
        assert tr.ages[k] == (k - max(got) if got else -1)
    assert (tr.ages >= 3).any()  # the exhausted policy was exercised


def test_arrivals_validation():
    with pytest.raises(InvalidInput) as err:
        simulate(PAPER, EQ23_GAINS, 3, x0=[1, 1], steps=10, arrivals=[(0, 0), (5, 3)])
    assert err.value.field == ("arrivals", 1) and "before it was sent" in str(err.value)
    with pytest.raises(InvalidInput) as err:
        simulate(PAPER, EQ23_GAINS, 3, x0=[1, 1], steps=10, arrivals=[(-1, 0)])
    assert err.value.field == ("arrivals", 0)
    with pytest.raises(InvalidInput) as err:
        simulate(PAPER, EQ23_GAINS, x0=[1, 1], steps=10)
    assert err.value.field == ("n_drop",)


def test_export_c_header_names_the_network(tmp_path):
    net = Network.delays(2, 3)
    files = export_c(EQ23_GAINS, network=net)
    head = files["ncs_controller.h"]
    assert "network: delays(max_delay=2, n_drop=3) (the network the gains are certified for)" in head
    assert "#define NCS_N_DROP 3" in head
    build(tmp_path, files)  # still strict C99
    with pytest.raises(InvalidInput) as err:
        export_c(EQ23_GAINS, 2, network=net)
    assert err.value.field == ("n_drop",)
