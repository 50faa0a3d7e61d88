"""C99 code for the predictive controller and the actuator's buffer (docs/design.md, "Deployment").

:func:`export_c` turns gains into two files: a header and a source with no
dynamic memory and no state outside the caller's ``<prefix>_buffer_t`` (the
gains are a ``static const`` table).  The controller side computes the packet
``[K_1 x, ..., K_N x]``; the actuator side keeps the newest packet and plays
``K_{d+1} x(stamp)`` with ``d = now - stamp`` while ``d < N``, then the
exhausted policy.

The actuator's clock
--------------------
``now`` is the sample index of the next ``<prefix>_buffer_output`` call: it is
0 after ``<prefix>_buffer_init`` (``<prefix>_buffer_set_clock`` sets it), and
each ``<prefix>_buffer_output`` returns ``u(now)`` and then advances ``now`` by
one.  A packet received before the output of sample k with stamp k is applied
at k (``d = 0``): that is the effective step of :func:`solver.simulate`.

Stamps are ``uint32_t`` sample indices and wrap around modulo 2^32: every
decision uses the age ``d`` of the held packet (saturating at 2^31 - 1), so the
wraparound of ``now`` and ``stamp`` is harmless.  A received packet's age is
``(uint32_t)(now - stamp)``; ages of 2^31 - 1 or more (a stamp ahead of the
actuator's clock, or older than 2^31 - 1 samples) are ignored.  The held
packet's stamp is kept too: ``<prefix>_buffer_set_clock`` recomputes its age
from it (and drops it when the stamp is ahead of the new clock), so the newest
stamp wins whenever the clock is set.

Precision
---------
``precision="float32"`` stores ``fl32(K)`` and computes in ``float``; the
certificate is re-checked on the rounded gains with the float32 rounding of
``K x`` as a bounded perturbation (:mod:`solver.precision`), and the export is
refused when that proof fails.  The code is MISRA C:2012 clean under cppcheck's
addon (deviations: docs/design.md, "Deployment").
"""

from __future__ import annotations

import re

import numpy as np

from .errors import InvalidInput
from .network import check_gains, check_n_drop
from .precision import PRECISIONS, certify_float32, packet_error_bound

EXHAUSTED = ("hold", "zero")

_IDENT = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,30}\Z")

#: Characters metadata keeps in the header comment; every other one becomes ``_``.  No ``*``, ``/``, ``\\``,
#: ``?`` or ``%`` (no comment delimiter, trigraph, line splice or format directive can be formed), no
#: control characters (no new line, so no preprocessor line).
_META_SAFE = frozenset("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789 _-.,:;=+()[]@#!&<>|~^'\"")
_META_KEY_MAX, _META_VALUE_MAX, _META_ITEMS_MAX = 40, 120, 32


def _comment_text(value, limit: int) -> str:
    """Text safe inside a C block comment: characters of ``_META_SAFE`` only, at most ``limit`` of them."""
    text = "".join(ch if ch in _META_SAFE else "_" for ch in str(value))
    return text if len(text) <= limit else text[:limit - 3] + "..."


def metadata_lines(metadata: dict) -> list[str]:
    """``key: value`` lines of the header comment, made safe (:data:`_META_SAFE`); at most 32 items.

    Raises
    ------
    InvalidInput
        When metadata is not a dict with string keys.
    """
    if not isinstance(metadata, dict) or not all(isinstance(k, str) for k in metadata):
        raise InvalidInput("metadata must be a dict with str keys", ("metadata",))
    lines = [f"{_comment_text(k, _META_KEY_MAX)}: {_comment_text(v, _META_VALUE_MAX)}"
             for k, v in list(metadata.items())[:_META_ITEMS_MAX]]
    return lines or ["(no design metadata given)"]


def _number(x: float, precision: str) -> str:
    if precision == "float32":
        # the shortest decimal of the float32 value (exact as a double) parses back to the same float
        text = repr(float(np.float32(x)))
        return (text if ("e" in text or "." in text) else text + ".0") + "f"
    text = repr(float(x))  # 17 significant digits round-trip every double exactly
    return text if ("e" in text or "." in text) else text + ".0"


def _times(expr: str, factor: int, macro: str) -> str:
    """``expr * MACRO`` (no multiplication by one: MISRA rule 2.2 reads it as dead code)."""
    return expr if factor == 1 else f"(({expr}) * {macro})"


def export_c(gains, n_drop: int | None = None, exhausted: str = "hold", prefix: str = "ncs", *,
             metadata: dict | None = None, precision: str = "float64", family=None,
             network=None) -> dict[str, str]:
    """C99 sources of the controller's packet and the actuator's buffer.

    Parameters
    ----------
    gains : array_like, shape (n_drop, m, n), or DesignResult
        ``gains[q-1] = K_q``.  A :class:`solver.DesignResult` gives its gains and,
        in the header comment, its method and certificate kind; with ``precision="float32"``
        also the claim to re-check (its decay rate, plant switching and certificate).
    n_drop : int
        Drop bound N: the packet holds N predicted inputs.
    exhausted : {"hold", "zero"}
        Input once the newest packet is ``N`` or more samples old: keep playing
        its last entry ``K_N x(stamp)`` (``"hold"``) or apply zero (``"zero"``).
    prefix : str
        Prefix of every C name and of the file names, lower-cased for files, functions and
        types (``<prefix>_controller.h``, ``<prefix>_buffer_t``), upper-cased for macros
        (``<PREFIX>_N``).  A letter, then letters, digits or ``_``; at most 31 characters.
    metadata : dict, optional
        Named in the header comment: ``id``, ``method``, ``certificate`` (kind) and
        anything else (str keys; at most 32 items, keys of 40 and values of 120 characters).
        Characters other than letters, digits, space and ``_-.,:;=+()[]@#!&<>|~^'"`` are
        written as ``_`` (no comment delimiter, trigraph, line splice or new line can be formed).
    precision : {"float64", "float32"}
        The C type of gains, states and inputs (``double`` or ``float``).  ``"float32"`` rounds
        the gains to float32 and re-checks the certificate on the loop the float32 code closes
        (docs/design.md, "Single precision"); it needs ``family``.
    family : PlantFamily, optional
        The plant, for the float32 re-check.
    network : Network, dict or str, optional
        The network the gains are certified for (:class:`solver.Network`); the header names it
        (``network: delays(max_delay=2, n_drop=3)``) and ``n_drop`` defaults to its ``n_drop``.

    Returns
    -------
    dict of str to str
        ``{"<prefix>_controller.h": ..., "<prefix>_controller.c": ...}``.

    Raises
    ------
    InvalidInput
        Bad arguments; with ``precision="float32"`` also when the rounded gains lose the proof
        (field ``precision``, the reason in the message).

    Notes
    -----
    The C interface (``ncs`` stands for ``prefix``, ``real`` for ``double`` or ``float``)::

        size_t ncs_buffer_size(void);
        void ncs_packet(const real x[], real packet[]);      /* packet[q*M + j] = (K_{q+1} x)_j */
        void ncs_buffer_init(ncs_buffer_t *b);                 /* no packet, now = 0 */
        void ncs_buffer_set_clock(ncs_buffer_t *b, uint32_t now);
        void ncs_buffer_receive(ncs_buffer_t *b, const real packet[], uint32_t stamp);
        void ncs_buffer_output(ncs_buffer_t *b, real u[]);    /* u(now), then now += 1 */

    ``receive`` keeps the packet only when it is newer than the one held (a
    smaller age ``now - stamp``); older and duplicate stamps are ignored.
    ``output`` gives zeros before the first packet.  See the module docstring
    for the clock and the wraparound of stamps.  Worst case per call: ``packet``
    N m n multiply-adds; ``receive``, ``output`` and ``set_clock`` none (copies only).
    """
    meta = dict(metadata or {}) if metadata is None or isinstance(metadata, dict) else metadata
    if not isinstance(meta, dict):
        raise InvalidInput("metadata must be a dict with str keys", ("metadata",))
    claim = {}
    if hasattr(gains, "gains") and hasattr(gains, "outcome"):  # a DesignResult
        result = gains
        if result.gains is None:
            raise InvalidInput(f"the design has no gains (outcome {result.outcome!r})", ("gains",))
        meta.setdefault("method", result.method)
        meta.setdefault("outcome", result.outcome)
        if result.certificate is not None:
            meta.setdefault("certificate", result.certificate.kind)
        scaled = bool(result.scaling) and result.scaling.get("certificate") == "scaled"
        claim = {"decay_rate": result.decay_rate if result.outcome == "stabilized" else None,
                 "plant_switching": result.plant_switching,
                 "certificate": None if scaled or result.outcome != "stabilized" else result.certificate}
        gains = result.gains
        if network is None and getattr(result, "network", None) is not None:
            network = result.network
    if network is not None:
        from .networks import check_network

        net = check_network(network, n_drop)
        n_drop = net.n_drop
        meta["network"] = f"{net.describe()} (the network the gains are certified for)"
        if precision == "float32" and not net.is_bounded_drops:
            raise InvalidInput(f"precision='float32' re-checks certificates on the paper's network only, not on "
                               f"{net.describe()}: export with precision='float64'", ("precision",))
    n_drop = check_n_drop(n_drop)
    try:
        K = np.array(gains, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidInput("gains must be an array of shape (n_drop, m, n)", ("gains",)) from None
    if K.ndim == 2 and K.shape[0] == n_drop:  # m = 1 given as (n_drop, n)
        K = K[:, None, :]
    if K.ndim != 3:
        raise InvalidInput("gains must be an array of shape (n_drop, m, n)", ("gains",))
    K = check_gains(K, n_drop, K.shape[1], K.shape[2])
    if exhausted not in EXHAUSTED:
        raise InvalidInput(f"exhausted must be one of {EXHAUSTED}, got {exhausted!r}", ("exhausted",))
    if not isinstance(prefix, str) or not _IDENT.match(prefix):
        raise InvalidInput("prefix must be a C identifier (a letter, then letters, digits or _; at most 31)",
                           ("prefix",))
    if precision not in PRECISIONS:
        raise InvalidInput(f"precision must be one of {PRECISIONS}, got {precision!r}", ("precision",))
    described = metadata_lines(meta)
    _, m, n = K.shape
    if precision == "float32":
        described.extend(_float32_lines(family, K, n_drop, claim))
    p, P = prefix.lower(), prefix.upper()
    real = "double" if precision == "float64" else "float"
    zero = "0.0" if precision == "float64" else "0.0f"
    length = n_drop * m
    header = _HEADER.format(p=p, P=P, n=n, m=m, N=n_drop, exhausted=exhausted, hold=int(exhausted == "hold"),
                            design="\n".join(f" *   {line}" for line in described), real=real,
                            precision=precision, length=length, macs=n_drop * m * n, copies=length)
    rows = ",\n".join(
        "        { /* K_%d */\n%s\n        }" % (q + 1, ",\n".join(
            "            {" + ", ".join(_number(v, precision) for v in K[q, j]) + "}" for j in range(m)))
        for q in range(n_drop))
    last = _times(f"{P}_N_DROP - 1u", m, f"{P}_M")
    source = _SOURCE.format(p=p, P=P, rows=rows, exhausted=exhausted, real=real, zero=zero,
                            entry=_times("b->age", m, f"{P}_M"), last=last)
    return {f"{p}_controller.h": header, f"{p}_controller.c": source}


def _float32_lines(family, K: np.ndarray, n_drop: int, claim: dict) -> list[str]:
    """Header lines of the float32 proof; InvalidInput with the reason when the rounded gains lose it."""
    from .plant import PlantFamily

    if not isinstance(family, PlantFamily):
        raise InvalidInput("precision='float32' needs the plant family (family=...) to re-check the certificate "
                           "on the rounded gains", ("family",))
    if (family.n_states, family.n_inputs) != K.shape[1:][::-1]:
        raise InvalidInput(f"the family has n = {family.n_states}, m = {family.n_inputs}; the gains are "
                           f"{K.shape[1]} x {K.shape[2]}", ("family",))
    proof = certify_float32(family, K, n_drop, plant_switching=claim.get("plant_switching", "per_interval"),
                            decay_rate=claim.get("decay_rate"), certificate=claim.get("certificate"))
    if not proof.verified:
        raise InvalidInput(proof.reason, ("precision",))
    return [f"float32: gains rounded to float32; {proof.claim} re-checked on them ({proof.source} certificate, "
            f"relative margin {proof.margin:.3g})",
            f"float32: |u - K x| <= {packet_error_bound(K):.4g} |K| |x| + 2^-126 (n + |K| 1) per entry; the "
            f"rounding uses "
            f"{proof.rounding_share:.3g} of the certificate's room"]


_HEADER = """\
/* {p}_controller.h: networked predictive controller and actuator buffer (C99, MISRA C:2012).
 *
 * Generated by ncs-design (solver.export_c). Design:
{design}
 * Sizes: {n} states, {m} inputs, packets of N = {N} predicted inputs; exhausted policy "{exhausted}".
 * Arithmetic: {precision} ({real}).
 *
 * Worst case per call: {p}_packet {macs} multiply-adds (N m n) and {copies} stores;
 * {p}_buffer_receive and {p}_buffer_output 0 multiply-adds (copies: {copies} and {m} values);
 * {p}_buffer_set_clock and {p}_buffer_init no arithmetic on reals. No loop bound depends on data.
 *
 * Controller node: each sample k, measure x(k), call {p}_packet(x, packet) and send
 * (packet, stamp = k). Actuator node: call {p}_buffer_receive for every packet that
 * arrived, then {p}_buffer_output once per sample.
 *
 * The actuator's clock `now`: 0 after {p}_buffer_init ({p}_buffer_set_clock sets it);
 * {p}_buffer_output returns u(now) and then advances now by one. With d = now - stamp
 * of the newest packet received, u = K_(d+1) x(stamp) while d < N; then "hold" keeps
 * K_N x(stamp) and "zero" applies 0. Zeros before the first packet. A packet replaces
 * the held one only when its stamp is newer; older and duplicate stamps are ignored.
 * Stamps are uint32_t sample indices modulo 2^32 (wraparound is handled: decisions use
 * ages); a stamp ahead of `now` or 2^31 - 1 or more samples old is ignored. Setting the
 * clock recomputes the held packet's age from its stamp (and drops it if its stamp is
 * ahead of the new clock), so the newest stamp always wins.
 *
 * No dynamic memory, no recursion, no calls outside this file (a compiler may make memset of the
 * zeroing loops, and soft-float helpers without an FPU), no state outside the caller's {p}_buffer_t.
 */
#ifndef {P}_CONTROLLER_H
#define {P}_CONTROLLER_H

#include <stddef.h>
#include <stdint.h>

#define {P}_N {n}u
#define {P}_M {m}u
#define {P}_N_DROP {N}u
#define {P}_PACKET_LEN {length}u
#define {P}_EXHAUSTED_HOLD {hold}

typedef struct {{
    {real} packet[{P}_PACKET_LEN]; /* the held packet: entry q at packet[q*M .. q*M + M - 1] */
    uint32_t now;                   /* sample index of the next output */
    uint32_t stamp;                 /* stamp of the held packet */
    uint32_t age;                   /* now - stamp of the held packet, saturating at 2^31 - 1 */
    uint32_t has_packet;            /* 0 until the first packet is received */
}} {p}_buffer_t;

/* Bytes of {p}_buffer_t, for callers that allocate it themselves. */
size_t {p}_buffer_size(void);
/* Controller: packet[q*{P}_M + j] = (K_(q+1) x)_j for q < {P}_N_DROP. */
void {p}_packet(const {real} x[], {real} packet[]);
/* Actuator: empty buffer, now = 0. */
void {p}_buffer_init({p}_buffer_t *b);
/* Actuator: set now (the sample index of the next output); the held packet's age is recomputed from its stamp. */
void {p}_buffer_set_clock({p}_buffer_t *b, uint32_t now);
/* Actuator: a packet measured at sample `stamp`; kept only if newer than the held one. */
void {p}_buffer_receive({p}_buffer_t *b, const {real} packet[], uint32_t stamp);
/* Actuator: u for this sample ({P}_M entries); then the buffer's clock advances. */
void {p}_buffer_output({p}_buffer_t *b, {real} u[]);

#endif /* {P}_CONTROLLER_H */
"""

_SOURCE = """\
/* {p}_controller.c: see {p}_controller.h. Generated by ncs-design (solver.export_c). */
#include "{p}_controller.h"

/* Ages at or above this are out of range (a stamp ahead of the clock, or too old to tell). */
#define {P}_AGE_LIMIT 0x7FFFFFFFu

static void {p}_copy({real} u[], const {real} v[])
{{
    uint32_t j;
    for (j = 0u; j < {P}_M; ++j) {{
        u[j] = v[j];
    }}
}}

#if {P}_EXHAUSTED_HOLD == 0
static void {p}_zero({real} u[])
{{
    uint32_t j;
    for (j = 0u; j < {P}_M; ++j) {{
        u[j] = {zero};
    }}
}}
#endif

size_t {p}_buffer_size(void)
{{
    return sizeof({p}_buffer_t);
}}

void {p}_packet(const {real} x[], {real} packet[])
{{
    /* K_(q+1) = {p}_gains[q]: {P}_M x {P}_N, row j gives input j. */
    static const {real} {p}_gains[{P}_N_DROP][{P}_M][{P}_N] = {{
{rows}
    }};
    uint32_t q;
    uint32_t j;
    uint32_t i;
    uint32_t k = 0u;
    for (q = 0u; q < {P}_N_DROP; ++q) {{
        for (j = 0u; j < {P}_M; ++j) {{
            {real} s = {zero};
            for (i = 0u; i < {P}_N; ++i) {{
                s += {p}_gains[q][j][i] * x[i];
            }}
            packet[k] = s;
            ++k;
        }}
    }}
}}

void {p}_buffer_init({p}_buffer_t *b)
{{
    uint32_t i;
    for (i = 0u; i < {P}_PACKET_LEN; ++i) {{
        b->packet[i] = {zero};
    }}
    b->now = 0u;
    b->stamp = 0u;
    b->age = {P}_AGE_LIMIT;
    b->has_packet = 0u;
}}

void {p}_buffer_set_clock({p}_buffer_t *b, uint32_t now)
{{
    b->now = now;
    if (b->has_packet != 0u) {{
        /* The age follows the stamp, not the old clock: a newer stamp must still win. */
        uint32_t age = (uint32_t)(now - b->stamp);
        if (age >= {P}_AGE_LIMIT) {{
            b->has_packet = 0u; /* its stamp is ahead of the new clock (or too old to order) */
            b->age = {P}_AGE_LIMIT;
        }} else {{
            b->age = age;
        }}
    }}
}}

void {p}_buffer_receive({p}_buffer_t *b, const {real} packet[], uint32_t stamp)
{{
    /* Unsigned subtraction is modulo 2^32: the age is right across a wraparound. */
    uint32_t age = (uint32_t)(b->now - stamp);
    uint32_t newer = 1u;
    if (age >= {P}_AGE_LIMIT) {{
        newer = 0u; /* from the future, or too old to order */
    }} else if ((b->has_packet != 0u) && (age >= b->age)) {{
        newer = 0u; /* not newer than the held packet */
    }} else {{
        /* newer: kept below */
    }}
    if (newer != 0u) {{
        uint32_t i;
        for (i = 0u; i < {P}_PACKET_LEN; ++i) {{
            b->packet[i] = packet[i];
        }}
        b->stamp = stamp;
        b->age = age;
        b->has_packet = 1u;
    }}
}}

void {p}_buffer_output({p}_buffer_t *b, {real} u[])
{{
    if (b->has_packet == 0u) {{
        uint32_t j;
        for (j = 0u; j < {P}_M; ++j) {{
            u[j] = {zero};
        }}
    }} else if (b->age < {P}_N_DROP) {{
        {p}_copy(u, &b->packet[{entry}]);
    }} else {{
#if {P}_EXHAUSTED_HOLD
        {p}_copy(u, &b->packet[{last}]); /* exhausted: "hold" */
#else
        {p}_zero(u); /* exhausted: "zero" */
#endif
    }}
    b->now += 1u;
    if ((b->has_packet != 0u) && (b->age < {P}_AGE_LIMIT)) {{
        b->age += 1u;
    }}
}}
"""
