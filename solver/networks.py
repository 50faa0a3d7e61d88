"""Networks as automata of buffer ages: delays, reordering, drops and weakly-hard patterns.

The actuator's buffer holds the newest-stamped control packet it has received.
At sample ``t`` its **age** is ``d(t) = t - stamp`` and it applies
``u(t) = K_{d(t)+1} x(t - d(t))``.  An older packet never replaces a newer one,
so ``d(t+1) <= d(t) + 1``, with equality when no newer packet arrives.

A :class:`Network` is a finite automaton whose nodes carry an age; its runs
(from any node) are exactly the admissible age sequences.  The closed loop is a
switched linear system on the augmented state
``xi(t) = (x(t), x(t-1), ..., x(t-N+1))`` (``N = n_drop``, the number of
gains), whose switching the automaton constrains: :func:`loop_matrices`
(docs/design.md, "Networks: delays and weakly-hard patterns").

The paper's network (a packet arrives in its own sample or never, at most
``n_drop - 1`` losses in a row) is :meth:`Network.bounded_drops`; callers take
today's interval-based code paths for it (:attr:`Network.is_bounded_drops`).
"""

from __future__ import annotations

import itertools
from collections import deque

import numpy as np

from .errors import InvalidInput

#: Largest automaton built (nodes); larger ones are refused up front.
MAX_NODES = 20_000
#: Most edges a built-in constructor builds (checked from its parameters before anything is allocated).
MAX_EDGES = 400_000

KINDS = ("bounded_drops", "delays", "weakly_hard", "automaton", "intersection")


def _n_drop(value) -> int:
    """``n_drop`` of a built-in network: an integer in 1..MAX_NODES (its ages are nodes)."""
    n_drop = _int(value, "n_drop", 1)
    if n_drop > MAX_NODES:
        raise InvalidInput(f"n_drop = {n_drop} makes more than {MAX_NODES} automaton nodes: use a smaller n_drop",
                           ("n_drop",))
    return n_drop


def _int(value, name: str, low: int, field: tuple | None = None) -> int:
    """An integer >= low (floats equal to an integer accepted), else InvalidInput naming the parameter."""
    field = (name,) if field is None else field
    if isinstance(value, bool):
        raise InvalidInput(f"{name} must be an integer >= {low}, got {value!r}", field)
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if not isinstance(value, (int, np.integer)):
        raise InvalidInput(f"{name} must be an integer >= {low}, got {value!r}", field)
    value = int(value)
    if value < low:
        raise InvalidInput(f"{name} must be an integer >= {low}, got {value}", field)
    return value


class Network:
    """A finite automaton of buffer ages (the admissible packet patterns of a network).

    Parameters
    ----------
    nodes : sequence of int
        The age (samples, >= 0) of every node; several nodes may share an age.
    edges : sequence of (int, int)
        Node index pairs: ``(i, j)`` lets the age go from ``nodes[i]`` at one sample to
        ``nodes[j]`` at the next.  Needs ``nodes[j] <= nodes[i] + 1`` (an older packet
        never replaces a newer one); every node needs an out-edge (runs go on forever).
    n_drop : int, optional
        Number of predictive gains N (ages up to ``N - 1`` are played from the buffer);
        default ``max(nodes) + 1``.
    name : str, optional
        Shown by :meth:`describe`.

    Attributes
    ----------
    n_drop : int
    nodes : int
        Number of automaton nodes.
    ages : ndarray of int, shape (nodes,)
    edges : list of (int, int)
    kind : {"bounded_drops", "delays", "weakly_hard", "automaton", "intersection"}
    params : dict
        The constructor's parameters (what :meth:`to_dict` writes).
    labels : list of str
        A readable name per node (e.g. the miss history of a weakly-hard node).

    Every node is a possible start: :meth:`admissible` accepts an age sequence when it
    is a run from some node.
    """

    def __init__(self, nodes, edges, *, n_drop=None, name=None, _kind="automaton", _params=None, _labels=None):
        try:
            ages = [a for a in nodes]
        except TypeError:
            raise InvalidInput("nodes must be a list of ages (integers >= 0), one per node", ("nodes",)) from None
        if not ages:
            raise InvalidInput("nodes must hold at least one age", ("nodes",))
        if len(ages) > MAX_NODES:
            raise InvalidInput(f"{len(ages)} nodes exceed the limit of {MAX_NODES}", ("nodes",))
        ages = [_int(a, f"nodes[{i}]", 0, ("nodes", i)) for i, a in enumerate(ages)]
        count = len(ages)
        try:
            pairs = [tuple(e) for e in edges]
        except TypeError:
            raise InvalidInput("edges must be a list of [i, j] node index pairs", ("edges",)) from None
        clean = []
        for k, e in enumerate(pairs):
            if len(e) != 2:
                raise InvalidInput(f"edges[{k}] must be a pair [i, j] of node indices", ("edges", k))
            i = _int(e[0], f"edges[{k}][0]", 0, ("edges", k, 0))
            j = _int(e[1], f"edges[{k}][1]", 0, ("edges", k, 1))
            if i >= count or j >= count:
                raise InvalidInput(f"edges[{k}] = [{i}, {j}] names a node outside 0..{count - 1}", ("edges", k))
            if ages[j] > ages[i] + 1:
                raise InvalidInput(
                    f"edges[{k}] goes from age {ages[i]} to age {ages[j]}: the age grows by at most 1 per sample "
                    "(an older packet never replaces a newer one); remove the edge or fix the ages", ("edges", k))
            clean.append((i, j))
        clean = sorted(set(clean))
        succ = [[] for _ in range(count)]
        for i, j in clean:
            succ[i].append(j)
        dead = [i for i in range(count) if not succ[i]]
        if dead:
            raise InvalidInput(
                f"node {dead[0]} (age {ages[dead[0]]}) has no out-edge: every node needs a successor "
                "(runs go on forever); add an edge from it, e.g. to an age-0 node", ("edges",))
        top = max(ages)
        if n_drop is None:
            n_drop = top + 1
        n_drop = _int(n_drop, "n_drop", 1)
        if top > n_drop - 1:
            raise InvalidInput(
                f"n_drop = {n_drop} gains cover ages 0..{n_drop - 1} but a node has age {top}: "
                f"use n_drop >= {top + 1}", ("n_drop",))
        self.n_drop = n_drop
        self.ages = np.array(ages, dtype=np.int64)
        self.ages.setflags(write=False)
        self.nodes = count
        self.edges = clean
        self._succ = succ
        self.kind = _kind
        self.name = None if name is None else str(name)
        self.params = dict(_params) if _params is not None else {
            "ages": list(ages), "edges": [list(e) for e in clean], "n_drop": n_drop}
        self.labels = list(_labels) if _labels is not None else [f"age {a}" for a in ages]

    # ------------------------------------------------------------ constructors
    @classmethod
    def bounded_drops(cls, n_drop) -> "Network":
        """The paper's network: a packet arrives in its own sample or never, at most ``n_drop - 1`` losses in a row.

        Ages ``0..n_drop-1``; ``d -> 0`` always and ``d -> d + 1`` while ``d + 1 <= n_drop - 1``.
        """
        n_drop = _n_drop(n_drop)
        edges = [(d, 0) for d in range(n_drop)] + [(d, d + 1) for d in range(n_drop - 1)]
        return cls(list(range(n_drop)), edges, n_drop=n_drop, _kind="bounded_drops",
                   _params={"n_drop": n_drop})

    @classmethod
    def delays(cls, max_delay, n_drop, min_delay=0) -> "Network":
        """Packets delayed by ``min_delay..max_delay`` samples, reordered, or lost; newest stamp wins.

        Packet ``k`` (stamped at sample ``k``) arrives at ``k + tau`` with
        ``min_delay <= tau <= max_delay``, or never, and the buffer's age stays
        ``<= n_drop - 1``.  So ``d(t+1)`` is ``d(t) + 1`` or any ``a`` with
        ``min_delay <= a <= min(max_delay, d(t))``.  ``max_delay = 0`` is :meth:`bounded_drops`.
        Ages below ``min_delay`` never occur (nodes ``min_delay..n_drop-1``).
        """
        n_drop = _n_drop(n_drop)
        max_delay = _int(max_delay, "max_delay", 0)
        min_delay = _int(min_delay, "min_delay", 0)
        if max_delay > n_drop - 1:
            raise InvalidInput(
                f"max_delay = {max_delay} needs n_drop >= {max_delay + 1} (a packet {max_delay} samples late is "
                f"played as K_{max_delay + 1}); got n_drop = {n_drop}", ("max_delay",))
        if min_delay > max_delay:
            raise InvalidInput(f"min_delay = {min_delay} must be <= max_delay = {max_delay}", ("min_delay",))
        if (n_drop - min_delay) * (max_delay - min_delay + 2) > MAX_EDGES:
            raise InvalidInput(f"delays(max_delay={max_delay}, n_drop={n_drop}) has about "
                               f"{(n_drop - min_delay) * (max_delay - min_delay + 2)} edges, more than {MAX_EDGES}: "
                               "use a smaller n_drop or max_delay", ("n_drop",))
        ages = list(range(min_delay, n_drop))
        index = {a: i for i, a in enumerate(ages)}
        edges = []
        for d in ages:
            if d + 1 <= n_drop - 1:
                edges.append((index[d], index[d + 1]))
            for a in range(min_delay, min(max_delay, d) + 1):
                edges.append((index[d], index[a]))
        params = {"max_delay": max_delay, "n_drop": n_drop, "min_delay": min_delay}
        if max_delay == 0:
            return cls(ages, edges, n_drop=n_drop, _kind="bounded_drops", _params={"n_drop": n_drop})
        return cls(ages, edges, n_drop=n_drop, _kind="delays", _params=params)

    @classmethod
    def weakly_hard(cls, misses, window, n_drop) -> "Network":
        """At most ``misses`` samples without a fresh packet in any ``window`` consecutive samples.

        A sample *misses* when no packet stamped at it arrives in it (age > 0); at most
        ``n_drop - 1`` misses in a row.  A node is the miss history of the last
        ``window - 1`` samples (the current one last) and the current age.
        """
        n_drop = _n_drop(n_drop)
        window = _int(window, "window", 1)
        misses = _int(misses, "misses", 0)
        if misses > window:
            raise InvalidInput(f"misses = {misses} must be <= window = {window}", ("misses",))
        h = window - 1
        if h > 16:
            raise InvalidInput(f"window = {window} is too long (at most 17: nodes grow as 2^(window-1))",
                               ("window",))

        # every miss history (the current sample last) with at most `misses` misses, and every age it allows:
        # the trailing misses are the age (capped at h), and a run of min(age, window) misses fits one window
        start = []
        for bits in itertools.product((0, 1), repeat=h):
            if sum(bits) > misses:
                continue
            trail = 0
            for b in reversed(bits):
                if not b:
                    break
                trail += 1
            for a in ([trail] if trail < h else range(h, n_drop)):
                if a <= n_drop - 1 and min(a, window) <= misses:
                    start.append((bits, a))
        nodes = {}
        order = []
        for s in start:
            if s not in nodes:
                nodes[s] = len(order)
                order.append(s)
        edges = []
        queue = deque(order)
        while queue:
            s = queue.popleft()
            bits, age = s
            for miss in (0, 1):
                new_age = age + 1 if miss else 0
                if new_age > n_drop - 1:
                    continue
                if sum(bits) + miss > misses:
                    continue
                nb = (bits + (miss,))[1:] if h else ()
                t = (nb, new_age)
                if t not in nodes:
                    if len(order) >= MAX_NODES:
                        raise InvalidInput(f"weakly_hard({misses}, {window}, {n_drop}) needs more than "
                                           f"{MAX_NODES} nodes", ("window",))
                    nodes[t] = len(order)
                    order.append(t)
                    queue.append(t)
                edges.append((nodes[s], nodes[t]))
        labels = ["".join("x" if b else "." for b in bits) + f"|age {a}" for bits, a in order]
        return cls([a for _, a in order], edges, n_drop=n_drop, _kind="weakly_hard",
                   _params={"misses": misses, "window": window, "n_drop": n_drop}, _labels=labels)

    def __and__(self, other: "Network") -> "Network":
        """Intersection: the age sequences admissible for both networks (product automaton)."""
        if not isinstance(other, Network):
            return NotImplemented
        n_drop = min(self.n_drop, other.n_drop)
        pairs = [(i, j) for i in range(self.nodes) for j in range(other.nodes)
                 if self.ages[i] == other.ages[j] and self.ages[i] <= n_drop - 1]
        if len(pairs) > MAX_NODES:
            raise InvalidInput(f"the intersection has {len(pairs)} nodes, more than {MAX_NODES}", ("network",))
        alive = set(pairs)
        succ = {p: [(a, b) for a in self._succ[p[0]] for b in other._succ[p[1]] if (a, b) in alive] for p in pairs}
        # drop dead ends until none is left: a run must go on forever
        changed = True
        while changed:
            changed = False
            for p in list(alive):
                if not any(q in alive for q in succ[p]):
                    alive.discard(p)
                    changed = True
        if not alive:
            raise InvalidInput(f"{self.describe()} and {other.describe()} admit no common infinite age sequence",
                               ("network",))
        keep = [p for p in pairs if p in alive]
        index = {p: k for k, p in enumerate(keep)}
        edges = [(index[p], index[q]) for p in keep for q in succ[p] if q in alive]
        labels = [f"{self.labels[i]} & {other.labels[j]}" for i, j in keep]
        return Network([int(self.ages[i]) for i, _ in keep], edges, n_drop=n_drop, _kind="intersection",
                       _params={"of": [self.to_dict(), other.to_dict()]}, _labels=labels)

    # ---------------------------------------------------------------- queries
    def successors(self, i) -> list:
        """Node indices reachable from node ``i`` in one sample."""
        i = _int(i, "i", 0)
        if i >= self.nodes:
            raise InvalidInput(f"node {i} outside 0..{self.nodes - 1}", ("i",))
        return list(self._succ[i])

    def admissible(self, ages) -> bool:
        """True when the finite age sequence is a run of the automaton from some node."""
        seq = [int(a) for a in ages]
        if not seq:
            return True
        current = {i for i in range(self.nodes) if self.ages[i] == seq[0]}
        for a in seq[1:]:
            if not current:
                return False
            current = {j for i in current for j in self._succ[i] if self.ages[j] == a}
        return bool(current)

    @property
    def is_bounded_drops(self) -> bool:
        """True when the admissible sequences are exactly those of ``bounded_drops(n_drop)``.

        Decided on the automaton: every edge is a paper step (``0`` or ``d + 1``), and the subset
        construction never meets a paper step the network refuses.
        """
        N = self.n_drop
        for i, j in self.edges:
            if not (self.ages[j] == 0 or self.ages[j] == self.ages[i] + 1):
                return False
        by_age = {}
        for i in range(self.nodes):
            by_age.setdefault(int(self.ages[i]), set()).add(i)
        if set(by_age) != set(range(N)):
            return False
        seen = set()
        stack = [frozenset(s) for s in by_age.values()]
        while stack:
            S = stack.pop()
            if S in seen:
                continue
            seen.add(S)
            if len(seen) > 100_000:
                return False
            d = int(self.ages[next(iter(S))])
            for a in ([0, d + 1] if d + 1 <= N - 1 else [0]):
                T = frozenset(j for i in S for j in self._succ[i] if self.ages[j] == a)
                if not T:
                    return False
                stack.append(T)
        return True

    def describe(self) -> str:
        """One line naming the network, e.g. ``"delays(max_delay=2, n_drop=3)"``."""
        if self.name:
            return self.name
        p = self.params
        if self.kind == "bounded_drops":
            return f"bounded_drops(n_drop={p['n_drop']})"
        if self.kind == "delays":
            extra = f", min_delay={p['min_delay']}" if p["min_delay"] else ""
            return f"delays(max_delay={p['max_delay']}, n_drop={p['n_drop']}{extra})"
        if self.kind == "weakly_hard":
            return f"weakly_hard(misses={p['misses']}, window={p['window']}, n_drop={p['n_drop']})"
        if self.kind == "intersection":
            return " & ".join(Network.from_dict(d).describe() for d in p["of"])
        return f"automaton({self.nodes} nodes, {len(self.edges)} edges, n_drop={self.n_drop})"

    def __repr__(self) -> str:
        return f"Network.{self.describe()}" if self.kind != "automaton" else f"<Network {self.describe()}>"

    def __eq__(self, other) -> bool:
        if not isinstance(other, Network):
            return NotImplemented
        return (self.n_drop == other.n_drop and np.array_equal(self.ages, other.ages)
                and self.edges == other.edges)

    def __hash__(self) -> int:
        return hash((self.n_drop, self.ages.tobytes(), tuple(self.edges)))

    # ---------------------------------------------------------- serialization
    def to_dict(self) -> dict:
        """JSON form: ``{"kind": "delays", "max_delay": 2, "n_drop": 3, "min_delay": 0}`` and the like."""
        if self.kind == "intersection":
            return {"kind": "intersection", "of": [dict(d) for d in self.params["of"]]}
        if self.kind == "automaton":
            return {"kind": "automaton", "ages": self.ages.tolist(), "edges": [list(e) for e in self.edges],
                    "n_drop": self.n_drop}
        return {"kind": self.kind, **self.params}

    @classmethod
    def from_dict(cls, d) -> "Network":
        """Inverse of :meth:`to_dict`; bad fields raise InvalidInput naming them."""
        if isinstance(d, Network):
            return d
        if not isinstance(d, dict):
            raise InvalidInput("network must be an object with a 'kind'", ())
        kind = d.get("kind")
        allowed = {
            "bounded_drops": {"n_drop"},
            "delays": {"max_delay", "n_drop", "min_delay"},
            "weakly_hard": {"misses", "window", "n_drop"},
            "automaton": {"ages", "edges", "n_drop"},
            "intersection": {"of"},
        }
        if kind not in allowed:
            raise InvalidInput(f"network kind must be one of {KINDS}, got {kind!r}", ("kind",))
        extra = set(d) - allowed[kind] - {"kind"}
        if extra:
            raise InvalidInput(f"unknown field {sorted(extra)[0]!r} for a {kind} network", (sorted(extra)[0],))
        required = {"bounded_drops": ("n_drop",), "delays": ("max_delay", "n_drop"),
                    "weakly_hard": ("misses", "window", "n_drop"), "automaton": ("ages", "edges"),
                    "intersection": ("of",)}[kind]
        for key in required:
            if key not in d:
                raise InvalidInput(f"a {kind} network needs {key!r}", (key,))
        if kind == "bounded_drops":
            return cls.bounded_drops(d["n_drop"])
        if kind == "delays":
            return cls.delays(d["max_delay"], d["n_drop"], d.get("min_delay", 0))
        if kind == "weakly_hard":
            return cls.weakly_hard(d["misses"], d["window"], d["n_drop"])
        if kind == "automaton":
            if not isinstance(d["ages"], (list, tuple)):
                raise InvalidInput("ages must be a list of integers", ("ages",))
            if not isinstance(d["edges"], (list, tuple)):
                raise InvalidInput("edges must be a list of [i, j] pairs", ("edges",))
            try:
                return cls(d["ages"], d["edges"], n_drop=d.get("n_drop"))
            except InvalidInput as err:
                field = ("ages",) + err.field[1:] if err.field[:1] == ("nodes",) else err.field
                raise InvalidInput(str(err).replace("nodes[", "ages["), field) from None
        of = d["of"]
        if not isinstance(of, (list, tuple)) or len(of) < 2:
            raise InvalidInput("'of' must list at least two networks", ("of",))
        nets = []
        for k, sub in enumerate(of):
            try:
                nets.append(cls.from_dict(sub))
            except InvalidInput as err:
                raise InvalidInput(str(err), ("of", k) + err.field) from None
        out = nets[0]
        for other in nets[1:]:
            out = out & other
        return out

    @classmethod
    def parse(cls, text: str) -> "Network":
        """CLI form: ``"drops:3"``, ``"delays:2,3"`` (max_delay, n_drop[, min_delay]), ``"weakly_hard:2,5,3"``.

        Several joined by ``&`` give their intersection.
        """
        if not isinstance(text, str) or not text.strip():
            raise InvalidInput("network must be text like 'drops:3', 'delays:2,3' or 'weakly_hard:2,5,3'",
                               ("network",))
        if "&" in text:
            parts = [cls.parse(p) for p in text.split("&")]
            out = parts[0]
            for p in parts[1:]:
                out = out & p
            return out
        head, _, rest = text.strip().partition(":")
        head = head.strip().lower()
        try:
            args = [int(a) for a in rest.split(",")] if rest.strip() else []
        except ValueError:
            raise InvalidInput(f"network {text!r}: the numbers after ':' must be integers separated by commas",
                               ("network",)) from None
        arity = {"drops": (1, 1), "bounded_drops": (1, 1), "delays": (2, 3), "weakly_hard": (3, 3)}
        if head not in arity:
            raise InvalidInput(f"network {text!r}: kind must be drops, delays or weakly_hard", ("network",))
        lo, hi = arity[head]
        if not lo <= len(args) <= hi:
            usage = {"drops": "drops:N", "bounded_drops": "drops:N", "delays": "delays:max_delay,n_drop[,min_delay]",
                     "weakly_hard": "weakly_hard:misses,window,n_drop"}[head]
            raise InvalidInput(f"network {text!r}: expected {usage}", ("network",))
        if head in ("drops", "bounded_drops"):
            return cls.bounded_drops(*args)
        if head == "delays":
            return cls.delays(*args)
        return cls.weakly_hard(*args)


def check_network(network, n_drop=None) -> Network:
    """A Network from a Network, its dict form or CLI text; ``n_drop``, when given too, must agree."""
    if isinstance(network, Network):
        net = network
    elif isinstance(network, dict):
        try:
            net = Network.from_dict(network)
        except InvalidInput as err:
            raise InvalidInput(str(err), ("network",) + err.field) from None
    elif isinstance(network, str):
        net = Network.parse(network)
    else:
        raise InvalidInput("network must be a Network, a dict like {'kind': 'delays', ...} or text like "
                           "'delays:2,3'", ("network",))
    if n_drop is not None and not isinstance(n_drop, bool) and n_drop != net.n_drop:
        raise InvalidInput(f"n_drop = {n_drop} disagrees with the network's n_drop = {net.n_drop} "
                           f"({net.describe()}); pass one of them", ("n_drop",))
    return net


def loop_matrices(family, gains, network) -> np.ndarray:
    """Closed-loop matrices on the augmented state, per plant mode and buffer age.

    With ``xi(t) = (x(t), x(t-1), ..., x(t-N+1))`` (``N = network.n_drop``) and age ``d`` at
    sample ``t``, ``x(t+1) = F_l x(t) + G_l K_{d+1} x(t-d)``, so ``xi(t+1) = A[l, d] xi(t)``.

    Parameters
    ----------
    family : PlantFamily
        r plant modes, n states, m inputs.
    gains : array_like, shape (N, m, n)
        ``gains[q-1] = K_q`` (for m = 1 also (N, n)).
    network : Network

    Returns
    -------
    ndarray, shape (r, N, n*N, n*N)
        ``A[l, d]``: the transition ``xi(t) -> xi(t+1)`` for plant mode l and age d at sample t.
    """
    from .network import check_gains

    net = check_network(network)
    N = net.n_drop
    n, m, r = family.n_states, family.n_inputs, family.n_modes
    K = check_gains(gains, N, m, n)
    A = np.zeros((r, N, n * N, n * N))
    for l in range(r):
        for d in range(N):
            A[l, d, :n, :n] = family.F[l]
            A[l, d, :n, d * n:(d + 1) * n] += family.G[l] @ K[d]
            for i in range(1, N):
                A[l, d, i * n:(i + 1) * n, (i - 1) * n:i * n] = np.eye(n)
    return A
