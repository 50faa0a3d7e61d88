"""Charge-then-release witnesses of a switched loop's l2 gain (docs/design.md §8.4, "Transient witness").

A periodic pattern's l2 gain, the lower end :func:`solver.brackets.lower_bound` finds, is what a disturbance gets
out of one pattern repeated from rest.  A switched loop can give more: a disturbance that drives the state up
under one pattern (the *charge*), after which the loop switches to a pattern that turns that state into output
without any disturbance (the *release*).  Over the best pair the energy ratio
``(|z|^2 over the charge + x' O x) / |w|^2`` (``O`` the release pattern's observability Gramian) can exceed every
periodic pattern's (a loop that switches from a slowly charging to a slowly releasing mode).

:func:`transient_witness` scores every pair of short stable patterns by ``lambda_max(W_c O_d)`` (``W_c`` the
charge's reachability Gramian: the charge run forever), picks the disturbance of the best pairs by the top
singular vector of the finite charge's operator, and evaluates the best in exact rational arithmetic on the loop
(the charge simulated exactly, the release's ``O`` bounded from below by a matrix whose Stein inequality is checked
exactly): a proven lower bound on the l2 gain of the infinite sequence "charge k times, then the release forever".
"""

from __future__ import annotations

import math
from fractions import Fraction
from typing import NamedTuple

import numpy as np

from . import periodic
from .exact import bits, exact, matmul, stein_floor, transpose

#: Pairs (charge, release) refined by their finite charge's top singular vector, the best by the Gramian score.
TRANSIENT_PAIRS = 4
#: Loop modes at most for which the patterns of two intervals (every ordered pair) charge and release too.
TRANSIENT_SHORT = 16
#: Disturbance entries at most in the charge (the columns of the charge's operator, whose top direction is sought).
TRANSIENT_INPUTS = 512
#: The charge runs until its state map's square has fallen to this (the Gramian's tail left out).
TRANSIENT_DECAY = 1e-6
#: Bits at most of an integer in the exact evaluation (the charge's state grows by the period's bits each period).
TRANSIENT_MAX_BITS = 200_000
#: Power steps at most on a charge's operator (its disturbance: a better one raises the value quadratically less).
POWER_STEPS = 60
#: Pairs times n^2 at most for the patterns of two intervals (the scores' stack; beyond it one interval only).
TRANSIENT_WORK = 4_000_000
#: Bits of the disturbance's entries (relative to its largest): a disturbance off by e costs e^2 of the value.
DISTURBANCE_BITS = 30


class Transient(NamedTuple):
    """A witness "``charge`` run ``periods`` times with the disturbance ``w``, then ``release`` forever at rest"."""

    #: A proven lower bound on that sequence's l2 gain (exact arithmetic, rounded down).
    value: float
    charge: tuple
    periods: int
    release: tuple
    #: Its float64 value (the search's).
    float_value: float
    #: Whether the exact evaluation ran on the deployed loop (else the float64 interval data as exact rationals).
    deployed: bool


def _sqrt_psd(M: np.ndarray) -> np.ndarray:
    w, V = np.linalg.eigh(0.5 * (M + np.swapaxes(M, -1, -2)))
    return (V * np.sqrt(np.maximum(w, 0.0))[..., None, :]) @ np.swapaxes(V, -1, -2)


def _candidates(data: list[dict]) -> list[tuple]:
    S, n = len(data), data[0]["A"].shape[0]
    pats = [(s,) for s in range(S)]
    if S <= TRANSIENT_SHORT and (S * S) ** 2 * n * n <= TRANSIENT_WORK:
        pats += [(s, u) for s in range(S) for u in range(S) if s != u]
    return pats


def _charge_operator(c: dict, k: int, release_root: np.ndarray) -> np.ndarray:
    """The map from the charge's disturbance (k periods) to its outputs and ``release_root x(end)``."""
    Phi, B, C, D = c["Phi"], c["B"], c["C"], c["D"]
    p, q, n = D.shape[0], D.shape[1], Phi.shape[0]
    powers = [B]  # Phi^i B
    for _ in range(k - 1):
        powers.append(Phi @ powers[-1])
    powers = np.stack(powers)
    lag = np.arange(k)[:, None] - 1 - np.arange(k)[None, :]  # block (i, j) is C Phi^(i-1-j) B below the diagonal
    blocks = np.where((lag >= 0)[:, :, None, None], np.einsum("pn,knq->kpq", C, powers)[np.maximum(lag, 0)], 0.0)
    blocks[np.arange(k), np.arange(k)] = D
    tail = np.einsum("nm,kmq->nkq", release_root, powers[::-1]).reshape(n, k * q)
    return np.vstack([blocks.transpose(0, 2, 1, 3).reshape(k * p, k * q), tail])


def _top_direction(op: np.ndarray, n: int) -> tuple[float, np.ndarray]:
    """``(|op v|, v)`` for a unit v near ``op``'s top right singular vector: power steps on ``op' op`` from the top
    right singular vector of its last n rows (the release's: the charge's Gramian direction), each step raising
    ``|op v|``; a full SVD of the (k p + n) x (k q) operator cost 0.07 s a pair at n = 12, 50 loop modes."""
    v = np.linalg.svd(op[-n:], full_matrices=False)[2][0]
    value = float(np.linalg.norm(op @ v))
    for _ in range(POWER_STEPS):
        u = op.T @ (op @ v)
        size = float(np.linalg.norm(u))
        if not size > 0:
            break
        u /= size
        new = float(np.linalg.norm(op @ u))
        if not new > value * (1 + 1e-12):
            break
        v, value = u, new
    return value, v


def transient_witness(data: list[dict], floor: float, patterns: list | None = None,
                      nodes: list | None = None) -> Transient | None:
    """The best charge-then-release witness found above ``floor`` (a gain), exactly evaluated, or None.

    ``data``: the loop modes' interval data (:meth:`solver.lifting.Lifted.numeric`, with a disturbance channel),
    any of which may follow any; or a network's transitions with ``patterns`` its closed walks (tuples of
    ``data`` indices) and ``nodes`` the node each starts from: a charge and a release then share their node.
    """
    from .brackets import exact_period, period_system

    if data[0].get("B") is None:
        return None
    n = data[0]["A"].shape[0]
    pats = _candidates(data) if patterns is None else [tuple(p) for p in patterns]
    systems = [period_system(data, p) for p in pats]
    Phi = np.stack([s["Phi"] for s in systems])
    BB = np.stack([s["B"] @ s["B"].T for s in systems])
    CC = np.stack([s["C"].T @ s["C"] for s in systems])
    O, stable, done = periodic.stein_screened(Phi, CC)
    W, stable_t, done_t = periodic.stein_screened(np.swapaxes(Phi, 1, 2), BB)
    ok = np.flatnonzero(stable & done & stable_t & done_t)
    if ok.size == 0:
        return None
    roots = _sqrt_psd(W[ok])
    # lambda_max(W_c O_d) = lambda_max(W_c^1/2 O_d W_c^1/2): the charge forever, then the release forever
    score = np.linalg.eigvalsh(roots[:, None] @ O[ok][None] @ roots[:, None])[..., -1]
    if nodes is not None:
        at = np.asarray(nodes)[ok]
        score[at[:, None] != at[None, :]] = -np.inf
    best = None
    for flat in np.argsort(score, axis=None)[::-1][:TRANSIENT_PAIRS]:
        if not np.isfinite(score.flat[flat]):
            break
        a, b = (int(ok[i]) for i in np.unravel_index(flat, score.shape))
        c = systems[a]
        radius = float(np.max(np.abs(np.linalg.eigvals(c["Phi"]))))
        need = 1 if radius < 1e-150 else math.ceil(math.log(TRANSIENT_DECAY) / (2.0 * math.log(radius)))
        k = max(1, min(need, TRANSIENT_INPUTS // max(1, c["B"].shape[1])))
        op = _charge_operator(c, k, _sqrt_psd(O[b]))
        value, v = _top_direction(op, n)
        if best is None or value > best[0]:
            best = (value, a, b, k, v)
    if best is None or not best[0] > floor:
        return None
    value, a, b, k, v = best
    exact_value = _exact_value(exact_period(data, pats[a]), exact_period(data, pats[b]), k, v, O[b],
                               systems[b]["Phi"])
    if exact_value is None or not exact_value[0] > floor:
        return None
    return Transient(exact_value[0], pats[a], k, pats[b], value, exact_value[1])


def _release_floor(release: dict, O: np.ndarray, Phif: np.ndarray) -> tuple | None:
    """A rational ``O_low <= O_true`` for the release period (exact ``(N, s)``), or None: :func:`solver.exact.
    stein_floor` of its state map and ``C'C`` (``O``, ``Phif``: float64 approximations of O_true and of the state
    map)."""
    (AB, sa), (CD, sc) = release["AB"], release["CD"]
    n = release["n"]
    Phi, C = (AB[:, :n], sa), (CD[:, :n], sc)
    return stein_floor(Phi, matmul(transpose(C), C), O, Phif)


def _exact_value(charge: dict | None, release: dict | None, k: int, v: np.ndarray, O: np.ndarray,
                 Phif: np.ndarray):
    """``(rounded-down gain, deployed)`` of the witness with disturbance ``v`` (k periods), exactly, or None
    (``O``, ``Phif``: the release's float64 Gramian and state map, :func:`_release_floor`)."""
    if charge is None or release is None:
        return None
    Ol = _release_floor(release, O, Phif)
    if Ol is None:
        return None
    n = charge["n"]
    (AB, sa), (CD, sc) = charge["AB"], charge["CD"]
    # a few bits of each entry (the integers then grow by the loop's bits only): any disturbance gives a lower bound
    Vn, u = exact(np.round(v / np.max(np.abs(v)) * 2.0 ** DISTURBANCE_BITS))
    q = AB.shape[1] - n
    x = (np.zeros((n, 1), dtype=object) * 0, 0)
    energy = Fraction(0)
    for i in range(k):
        w = (Vn[i * q:(i + 1) * q].reshape(q, 1), u)
        xw = (np.vstack([x[0] * (1 << u), w[0] * (1 << x[1])]), x[1] + u)  # [x; w] over one power of two
        z = matmul((CD, sc), xw)
        energy += Fraction(int(np.dot(z[0][:, 0], z[0][:, 0])), 1 << (2 * z[1]))
        x = matmul((AB, sa), xw)
        if bits(x[0]) > TRANSIENT_MAX_BITS:
            return None
    tail = matmul(matmul((x[0].T.copy(), x[1]), Ol), x)
    energy += Fraction(int(tail[0][0, 0]), 1 << tail[1])
    norm = Fraction(int(np.dot(Vn, Vn)), 1 << (2 * u))
    if norm == 0 or energy <= 0:
        return None
    ratio = energy / norm
    f = math.sqrt(float(ratio))
    while Fraction(f) ** 2 > ratio:  # rounded down: its square at most the ratio
        f = float(np.nextafter(f, 0.0))
    return f, bool(charge["deployed"] and release["deployed"])
