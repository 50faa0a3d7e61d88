"""Network automata against brute force from the definitions (docs/design.md, "Networks")."""

import itertools

import numpy as np
import pytest

from solver import InvalidInput, Network, PlantFamily
from solver.networks import loop_matrices


def all_sequences(n_drop, length):
    return itertools.product(range(n_drop), repeat=length)


def ages_from_deliveries(n_drop, length, min_delay, max_delay):
    """Every age sequence over samples 0..length-1 produced by explicit packet delays.

    Packets stamped -(n_drop-1) .. length-1 each arrive ``tau`` samples late (min_delay <= tau <= max_delay)
    or never; the buffer holds the newest stamp arrived so far; runs whose age ever exceeds n_drop-1 are out.
    """
    stamps = list(range(-(n_drop - 1), length))
    choices = list(range(min_delay, max_delay + 1)) + [None]
    found = set()
    for delays in itertools.product(choices, repeat=len(stamps)):
        arrivals = [(s + tau, s) for s, tau in zip(stamps, delays) if tau is not None]
        seq = []
        for t in range(length):
            got = [s for a, s in arrivals if a <= t]
            if not got or t - max(got) > n_drop - 1:
                break
            seq.append(t - max(got))
        else:
            found.add(tuple(seq))
    return found


def ages_from_miss_windows(misses, window, n_drop, length):
    """Every age sequence of the last ``length`` samples of miss patterns obeying both constraints."""
    pre = window + n_drop
    found = set()
    for bits in itertools.product((0, 1), repeat=pre + length):
        if bits[0]:
            continue  # a fresh packet long before: the age is known from there on
        if any(sum(bits[k:k + window]) > misses for k in range(len(bits) - window + 1)):
            continue
        ages, age = [], 0
        for b in bits:
            age = age + 1 if b else 0
            ages.append(age)
        if max(ages) > n_drop - 1:
            continue
        found.add(tuple(ages[pre:]))
    return found


def paper_sequences(n_drop, length):
    return {s for s in all_sequences(n_drop, length)
            if all(b == 0 or b == a + 1 for a, b in zip(s, s[1:]))}


@pytest.mark.parametrize("n_drop", [1, 2, 3, 4])
def test_bounded_drops_is_the_paper_network(n_drop):
    net = Network.bounded_drops(n_drop)
    assert net.n_drop == n_drop and net.nodes == n_drop and net.is_bounded_drops
    for length in (1, 2, 5):
        accepted = {s for s in all_sequences(n_drop, length) if net.admissible(s)}
        assert accepted == paper_sequences(n_drop, length)
    assert Network.delays(0, n_drop) == net and Network.delays(0, n_drop).is_bounded_drops


@pytest.mark.parametrize("min_delay, max_delay, n_drop", [(0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3), (1, 1, 3)])
def test_delays_match_explicit_packet_delays(min_delay, max_delay, n_drop):
    net = Network.delays(max_delay, n_drop, min_delay=min_delay)
    length = 5
    accepted = {s for s in all_sequences(n_drop, length) if net.admissible(s)}
    assert accepted == ages_from_deliveries(n_drop, length, min_delay, max_delay)
    assert not net.is_bounded_drops
    # one-sample delay with n_drop >= 2: a late packet's age 1 can follow age 1 (not a paper step)
    assert net.admissible([1, 1]) == (max_delay >= 1 and min_delay <= 1)


@pytest.mark.parametrize("misses, window, n_drop", [(2, 5, 3), (1, 3, 3), (1, 2, 2), (0, 1, 2), (3, 4, 2),
                                                    (2, 2, 3)])
def test_weakly_hard_matches_window_counting(misses, window, n_drop):
    net = Network.weakly_hard(misses, window, n_drop)
    length = 6
    accepted = {s for s in all_sequences(n_drop, length) if net.admissible(s)}
    assert accepted == ages_from_miss_windows(misses, window, n_drop, length)
    # the window constraint is void when the run bound implies it
    assert net.is_bounded_drops == (accepted == paper_sequences(n_drop, length))


def test_intersection_is_both():
    a, b = Network.delays(1, 3), Network.weakly_hard(2, 5, 3)
    both = a & b
    assert both.n_drop == 3 and both.kind == "intersection"
    for s in all_sequences(3, 6):
        assert both.admissible(s) == (a.admissible(s) and b.admissible(s))
    assert Network.from_dict(both.to_dict()) == both
    c = Network.delays(2, 4) & Network.bounded_drops(3)
    assert c.n_drop == 3 and c.is_bounded_drops


def test_general_automaton_and_successors():
    # ages 0 -> 1 -> 1 -> 0: a packet that is always exactly one sample late except every other
    net = Network([0, 1, 1], [(0, 1), (1, 2), (2, 0)], n_drop=2)
    assert net.nodes == 3 and net.n_drop == 2 and net.kind == "automaton"
    assert net.successors(1) == [2]
    assert net.admissible([0, 1, 1, 0, 1, 1]) and net.admissible([1, 0])
    assert not net.admissible([0, 0]) and not net.admissible([1, 1, 1])
    assert Network.from_dict(net.to_dict()) == net
    assert "automaton" in net.describe()


@pytest.mark.parametrize("net", [Network.bounded_drops(3), Network.delays(2, 3), Network.delays(1, 4, min_delay=1),
                                 Network.weakly_hard(2, 5, 3)])
def test_dict_and_text_round_trip(net):
    again = Network.from_dict(net.to_dict())
    assert again == net and again.describe() == net.describe()


def test_parse():
    assert Network.parse("drops:3") == Network.bounded_drops(3)
    assert Network.parse("delays:2,3") == Network.delays(2, 3)
    assert Network.parse("delays:2,3,1") == Network.delays(2, 3, min_delay=1)
    assert Network.parse("weakly_hard:2,5,3") == Network.weakly_hard(2, 5, 3)
    assert Network.parse("delays:1,3 & weakly_hard:2,5,3") == Network.delays(1, 3) & Network.weakly_hard(2, 5, 3)
    assert Network.delays(2, 3).describe() == "delays(max_delay=2, n_drop=3)"


@pytest.mark.parametrize("build, field, words", [
    (lambda: Network.bounded_drops(0), ("n_drop",), "n_drop"),
    (lambda: Network.delays(3, 3), ("max_delay",), "n_drop >= 4"),
    (lambda: Network.delays(1, 3, min_delay=2), ("min_delay",), "max_delay"),
    (lambda: Network.delays(-1, 3), ("max_delay",), "max_delay"),
    (lambda: Network.weakly_hard(6, 5, 3), ("misses",), "window"),
    (lambda: Network.weakly_hard(1, 0, 3), ("window",), "window"),
    (lambda: Network.weakly_hard(1.5, 3, 3), ("misses",), "misses"),
    (lambda: Network([0, 2], [(0, 1), (1, 0)]), ("edges", 0), "at most 1"),
    (lambda: Network([0, 1], [(0, 1)]), ("edges",), "no out-edge"),
    (lambda: Network([0, 1], [(0, 1), (1, 0)], n_drop=1), ("n_drop",), "n_drop >= 2"),
    (lambda: Network([0, -1], [(0, 1), (1, 0)]), ("nodes", 1), "nodes[1]"),
    (lambda: Network([0], [(0, 3)]), ("edges", 0), "outside"),
    (lambda: Network([], []), ("nodes",), "at least one"),
    (lambda: Network.from_dict({"kind": "delay", "n_drop": 3}), ("kind",), "kind"),
    (lambda: Network.from_dict({"kind": "delays", "n_drop": 3}), ("max_delay",), "max_delay"),
    (lambda: Network.from_dict({"kind": "delays", "max_delay": 1, "n_drop": 3, "x": 1}), ("x",), "'x'"),
    (lambda: Network.from_dict({"kind": "automaton", "ages": [0, 3], "edges": [[0, 1], [1, 0]]}), ("edges", 0),
     "age"),
    (lambda: Network.parse("delays:2"), ("network",), "max_delay,n_drop"),
    (lambda: Network.parse("jitter:2"), ("network",), "kind"),
])
def test_bad_networks_name_the_parameter(build, field, words):
    with pytest.raises(InvalidInput) as err:
        build()
    assert err.value.field == field
    assert words in str(err.value)


def test_loop_matrices_step_the_buffer():
    rng = np.random.default_rng(3)
    fam = PlantFamily(F=rng.normal(size=(2, 2, 2)), G=rng.normal(size=(2, 2, 1)))
    N = 3
    K = rng.normal(size=(N, 1, 2))
    A = loop_matrices(fam, K, Network.delays(2, N))
    assert A.shape == (2, N, 2 * N, 2 * N)
    xs = [rng.normal(size=2) for _ in range(N)]  # x(t-2), x(t-1), x(t)
    xi = np.concatenate(xs[::-1])
    for l, d in [(0, 0), (1, 2), (0, 1), (1, 1), (0, 2)]:
        x_next = fam.F[l] @ xs[-1] + fam.G[l] @ K[d] @ xs[-1 - d]
        xs.append(x_next)
        xi = A[l, d] @ xi
        np.testing.assert_allclose(xi, np.concatenate(xs[::-1][:N]), rtol=1e-12, atol=1e-12)


def test_huge_networks_are_refused_before_anything_is_built():
    import tracemalloc

    from solver import InvalidInput, Network

    tracemalloc.start()
    for make in (lambda: Network.delays(64, 10**9), lambda: Network.bounded_drops(10**9),
                 lambda: Network.weakly_hard(2, 5, 10**9), lambda: Network.delays(5000, 6000)):
        with pytest.raises(InvalidInput) as err:
            make()
        assert err.value.field == ("n_drop",)
    assert tracemalloc.get_traced_memory()[1] < 20 * 2**20  # refused up front, not after allocating
    tracemalloc.stop()
