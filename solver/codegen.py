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

Stamps are ``uint32_t`` sample indices and wrap around modulo 2^32: the buffer
stores the age ``d`` of its packet (saturating at 2^31 - 1), never an absolute
stamp, so the wraparound of ``now`` and ``stamp`` is harmless.  A received
packet's age is ``(uint32_t)(now - stamp)``; ages of 2^31 - 1 or more (a stamp
ahead of the actuator's clock, or older than 2^31 - 1 samples) are ignored.
"""

from __future__ import annotations

import re

import numpy as np

from .errors import InvalidInput
from .network import check_gains, check_n_drop

EXHAUSTED = ("hold", "zero")

_IDENT = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,30}\Z")


def _comment_text(value) -> str:
    """Text safe inside a C block comment (no comment terminator, printable ASCII)."""
    text = "".join(ch if 32 <= ord(ch) < 127 else "?" for ch in str(value))
    return text.replace("*/", "* /")


def _number(x: float) -> str:
    # 17 significant digits round-trip every double exactly.
    text = repr(float(x))
    return text if ("e" in text or "." in text or "inf" in text) else text + ".0"


def export_c(gains, n_drop: int | None = None, exhausted: str = "hold", prefix: str = "ncs", *,
             metadata: dict | None = None, network=None) -> dict[str, str]:
    """C99 sources of the controller's packet and the actuator's buffer.

    Parameters
    ----------
    gains : array_like, shape (n_drop, m, n), or DesignResult
        ``gains[q-1] = K_q``.  A :class:`solver.DesignResult` gives its gains and,
        in the header comment, its method and certificate kind.
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
        anything else (str keys, short values).
    network : Network, dict or str, optional
        The network the gains are certified for (:class:`solver.Network`); the header names it
        (``network: delays(max_delay=2, n_drop=3)``) and ``n_drop`` defaults to its ``n_drop``.

    Returns
    -------
    dict of str to str
        ``{"<prefix>_controller.h": ..., "<prefix>_controller.c": ...}``.

    Notes
    -----
    The C interface (``ncs`` stands for ``prefix``)::

        size_t ncs_buffer_size(void);
        void ncs_packet(const double x[], double packet[]);   /* packet[q*M + j] = (K_{q+1} x)_j */
        void ncs_buffer_init(ncs_buffer_t *b);                 /* no packet, now = 0 */
        void ncs_buffer_set_clock(ncs_buffer_t *b, uint32_t now);
        void ncs_buffer_receive(ncs_buffer_t *b, const double packet[], uint32_t stamp);
        void ncs_buffer_output(ncs_buffer_t *b, double u[]);  /* u(now), then now += 1 */

    ``receive`` keeps the packet only when it is newer than the one held (a
    smaller age ``now - stamp``); older and duplicate stamps are ignored.
    ``output`` gives zeros before the first packet.  See the module docstring
    for the clock and the wraparound of stamps.
    """
    meta = dict(metadata or {})
    if hasattr(gains, "gains") and hasattr(gains, "outcome"):  # a DesignResult
        result = gains
        if result.gains is None:
            raise InvalidInput(f"the design has no gains (outcome {result.outcome!r})", ("gains",))
        meta.setdefault("method", result.method)
        meta.setdefault("outcome", result.outcome)
        if result.certificate is not None:
            meta.setdefault("certificate", result.certificate.kind)
        gains = result.gains
        if network is None and getattr(result, "network", None) is not None:
            network = result.network
    if network is not None:
        from .networks import check_network

        net = check_network(network, n_drop)
        n_drop = net.n_drop
        meta["network"] = f"{net.describe()} (the network the gains are certified for)"
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
    _, m, n = K.shape
    p, P = prefix.lower(), prefix.upper()
    described = [f"{_comment_text(k)}: {_comment_text(v)}" for k, v in meta.items()]
    described = described or ["(no design metadata given)"]
    header = _HEADER.format(p=p, P=P, n=n, m=m, N=n_drop, exhausted=exhausted, hold=int(exhausted == "hold"),
                            design="\n".join(f" *   {line}" for line in described))
    rows = ",\n".join(
        "    { /* K_%d */\n%s\n    }" % (q + 1, ",\n".join(
            "        {" + ", ".join(_number(v) for v in K[q, j]) + "}" for j in range(m)))
        for q in range(n_drop))
    source = _SOURCE.format(p=p, P=P, rows=rows, exhausted=exhausted,
                            exhausted_code=(f"{p}_copy(u, &b->packet[({P}_N_DROP - 1) * {P}_M]);"
                                            if exhausted == "hold" else f"{p}_zero(u);"))
    return {f"{p}_controller.h": header, f"{p}_controller.c": source}


_HEADER = """\
/* {p}_controller.h: networked predictive controller and actuator buffer (C99).
 *
 * Generated by ncs-design (solver.export_c). Design:
{design}
 * Sizes: {n} states, {m} inputs, packets of N = {N} predicted inputs; exhausted policy "{exhausted}".
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
 * Stamps are uint32_t sample indices modulo 2^32 (wraparound is handled: the buffer
 * stores ages, not stamps); a stamp ahead of `now` or 2^31 - 1 or more samples old
 * is ignored.
 *
 * No dynamic memory and no state outside the caller's {p}_buffer_t.
 */
#ifndef {P}_CONTROLLER_H
#define {P}_CONTROLLER_H

#include <stddef.h>
#include <stdint.h>

#define {P}_N {n}
#define {P}_M {m}
#define {P}_N_DROP {N}
#define {P}_EXHAUSTED_HOLD {hold}

typedef struct {{
    double packet[{P}_N_DROP * {P}_M]; /* the held packet: entry q at packet[q*M .. q*M + M - 1] */
    uint32_t now;                       /* sample index of the next output */
    uint32_t age;                       /* now - stamp of the held packet, saturating at 2^31 - 1 */
    int has_packet;                     /* 0 until the first packet is received */
}} {p}_buffer_t;

/* Bytes of {p}_buffer_t, for callers that allocate it themselves. */
size_t {p}_buffer_size(void);
/* Controller: packet[q*{P}_M + j] = (K_(q+1) x)_j for q < {P}_N_DROP. */
void {p}_packet(const double x[], double packet[]);
/* Actuator: empty buffer, now = 0. */
void {p}_buffer_init({p}_buffer_t *b);
/* Actuator: set now (the sample index of the next output) to the controller's time base. */
void {p}_buffer_set_clock({p}_buffer_t *b, uint32_t now);
/* Actuator: a packet measured at sample `stamp`; kept only if newer than the held one. */
void {p}_buffer_receive({p}_buffer_t *b, const double packet[], uint32_t stamp);
/* Actuator: u for this sample ({P}_M entries); then the buffer's clock advances. */
void {p}_buffer_output({p}_buffer_t *b, double u[]);

#endif /* {P}_CONTROLLER_H */
"""

_SOURCE = """\
/* {p}_controller.c: see {p}_controller.h. Generated by ncs-design (solver.export_c). */
#include "{p}_controller.h"

/* Ages at or above this are out of range (a stamp ahead of the clock, or too old to tell). */
#define {P}_AGE_LIMIT 0x7FFFFFFFu

/* K_(q+1) = {p}_gains[q]: {P}_M x {P}_N, row j gives input j. */
static const double {p}_gains[{P}_N_DROP][{P}_M][{P}_N] = {{
{rows}
}};

static void {p}_copy(double u[], const double v[])
{{
    int j;
    for (j = 0; j < {P}_M; ++j) {{
        u[j] = v[j];
    }}
}}

static void {p}_zero(double u[])
{{
    int j;
    for (j = 0; j < {P}_M; ++j) {{
        u[j] = 0.0;
    }}
}}

size_t {p}_buffer_size(void)
{{
    return sizeof({p}_buffer_t);
}}

void {p}_packet(const double x[], double packet[])
{{
    int q, j, i;
    for (q = 0; q < {P}_N_DROP; ++q) {{
        for (j = 0; j < {P}_M; ++j) {{
            double s = 0.0;
            for (i = 0; i < {P}_N; ++i) {{
                s += {p}_gains[q][j][i] * x[i];
            }}
            packet[q * {P}_M + j] = s;
        }}
    }}
}}

void {p}_buffer_init({p}_buffer_t *b)
{{
    int i;
    for (i = 0; i < {P}_N_DROP * {P}_M; ++i) {{
        b->packet[i] = 0.0;
    }}
    b->now = 0u;
    b->age = {P}_AGE_LIMIT;
    b->has_packet = 0;
}}

void {p}_buffer_set_clock({p}_buffer_t *b, uint32_t now)
{{
    b->now = now;
}}

void {p}_buffer_receive({p}_buffer_t *b, const double packet[], uint32_t stamp)
{{
    /* Unsigned subtraction is modulo 2^32: the age is right across a wraparound. */
    uint32_t age = (uint32_t)(b->now - stamp);
    int i;
    if (age >= {P}_AGE_LIMIT) {{
        return; /* from the future, or too old to order */
    }}
    if (b->has_packet && age >= b->age) {{
        return; /* not newer than the held packet */
    }}
    for (i = 0; i < {P}_N_DROP * {P}_M; ++i) {{
        b->packet[i] = packet[i];
    }}
    b->age = age;
    b->has_packet = 1;
}}

void {p}_buffer_output({p}_buffer_t *b, double u[])
{{
    if (!b->has_packet) {{
        {p}_zero(u);
    }} else if (b->age < (uint32_t){P}_N_DROP) {{
        {p}_copy(u, &b->packet[b->age * {P}_M]);
    }} else {{
        {exhausted_code} /* exhausted: "{exhausted}" */
    }}
    b->now += 1u;
    if (b->has_packet && b->age < {P}_AGE_LIMIT) {{
        b->age += 1u;
    }}
}}
"""
