"""Figures of simulated runs and margin searches (matplotlib, headless).

Like the paper's Fig. 3/4: one column per run (e.g. one per plant mode),
states on top, inputs below, lost samples marked.  Rendering uses the Agg
backend through ``Figure`` directly, so it never touches a display or
pyplot's global state (safe in worker processes and threads).
"""

from __future__ import annotations

import io
from typing import Sequence

import matplotlib
import numpy as np
from matplotlib.figure import Figure

from .margins import MarginResult
from .simulate import SimulationResult

#: Formats :func:`render` produces, with their media types.
MEDIA_TYPES = {"svg": "image/svg+xml", "png": "image/png"}


#: The window of :func:`trace_figure` ends where the state norm has fallen below this fraction of its peak.
SETTLED_FRACTION = 1e-3
#: ... but shows at least this many samples.
MIN_WINDOW_SAMPLES = 10


def settling_time(trace: SimulationResult, fraction: float = SETTLED_FRACTION) -> float:
    """First time after which ``|x(k)|`` stays below ``fraction`` times its peak (the run's end if never).

    Parameters
    ----------
    trace : SimulationResult
    fraction : float
        Of the peak Euclidean norm of the state.

    Returns
    -------
    float
        In the units of ``trace.time`` (seconds, or samples without a sampling period).
    """
    norm = np.linalg.norm(trace.state, axis=1)
    above = np.flatnonzero(norm > fraction * norm.max())
    k = min(int(above[-1]) + 1 if above.size else 0, len(trace.time) - 1)
    return float(trace.time[k])


def default_window(traces: Sequence[SimulationResult]) -> float:
    """End of the time axis that fits every run's transient: the latest settling time plus 20 %,
    at least :data:`MIN_WINDOW_SAMPLES` samples, at most the runs' length."""
    end = max(float(tr.time[-1]) for tr in traces)
    step = min(float(tr.time[1] - tr.time[0]) for tr in traces)
    settle = max(settling_time(tr) for tr in traces)
    return float(min(end, max(1.2 * settle, MIN_WINDOW_SAMPLES * step)))


#: Plain words for the plant-switching options, for titles.
SWITCHING_WORDS = {"per_interval": "plant may switch when a packet arrives",
                   "per_sample": "plant may switch at every sample",
                   "none": "plant fixed"}


def mode_title(family, l: int) -> str:
    """A column title for a run with plant mode l fixed: the mode's name when the family has one."""
    names = getattr(family, "mode_names", None) if family is not None else None
    return f"Plant fixed: {names[l]}" if names else f"Plant mode {l} fixed"


def state_groups(family, n: int) -> list[list[int]]:
    """States that share one y-axis: those with the same unit; one axis per state when units are unknown."""
    names = getattr(family, "state_names", None) if family is not None else None
    units = (getattr(family, "units", None) or {}) if family is not None else {}
    if not names or not any(units.get(name) for name in names):
        return [[i] for i in range(n)]
    groups: dict = {}
    for i, name in enumerate(names):
        groups.setdefault(units.get(name) or ("?", i), []).append(i)
    return list(groups.values())


def trace_figure(traces: Sequence[SimulationResult], titles: Sequence[str] | None = None,
                 width: float = 10.0, height: float | None = None, dpi: int = 100, family=None,
                 t_max: float | None = None, settling: float | None = None, u_max=None) -> Figure:
    """States, inputs and the network/plant strip over time for each run (like the paper's Fig. 3/4).

    One column per run.  Top: one axis per group of states with the same unit (one per state when
    units are unknown), so an angle in rad is not flattened by a position in m; then the inputs
    (held over each sample, over the whole window); bottom strip: the active plant mode as a step
    trace and, below it, a tick at every sample without a new packet.  Rows share their y-axis
    across columns.  A dotted line marks where each run settled (2 % of ``|x(0)|``,
    :meth:`SimulationResult.settling_samples`), a dashed one the certified worst case when given.

    Parameters
    ----------
    traces : sequence of SimulationResult
        Runs of the same plant family (also the client's results: ``time``, ``state``, ``input``,
        ``mode``, ``effective`` are all that is read).
    titles : sequence of str, optional
    width, height : float
        Figure size in inches (pixels = inches * dpi for PNG); default height grows with the rows.
    dpi : int
    family : PlantFamily, optional
        Names, units and mode names for legends, axes and the strip; the time unit.
    t_max : float, optional
        End of the time axis (s, or samples); default: the whole simulated window.
    settling : float, optional
        The certified settling time (``DesignResult.settling["seconds"]``), drawn as a dashed line.
    u_max : sequence of float, optional
        Input limits (one per input) drawn as dashed lines at ``+-u_max[j]`` (a design with ``u_max`` keeps
        every input inside them from its invariant set, docs/design.md §8).
    """
    cols = max(len(traces), 1)
    n = traces[0].state.shape[1] if traces else (family.n_states if family is not None else 1)
    groups = state_groups(family, n)
    # Runs on a network (late packets) carry the buffer's age per sample: a row of its own.
    has_ages = any(_network_run(tr) for tr in traces)
    rows = len(groups) + 2 + int(has_ages)
    if height is None:
        height = 1.6 * len(groups) + 3.2 + 1.2 * int(has_ages)
    fig = Figure(figsize=(width, height), dpi=dpi, layout="constrained")
    axes = fig.subplots(rows, cols, sharex="col", sharey="row", squeeze=False,
                        gridspec_kw={"height_ratios": [2] * len(groups) + [2] + [1.4] * int(has_ages) + [1.4]})
    timed = (family.sampling_period is not None) if family is not None else (
        bool(traces) and float(traces[0].time[1] - traces[0].time[0]) != 1.0)
    n_modes = family.n_modes if family is not None else (
        1 + max((int(np.max(tr.mode)) for tr in traces if len(tr.mode)), default=0))
    end = t_max if t_max is not None else (max(float(tr.time[-1]) for tr in traces) if traces else 1.0)
    colors = matplotlib.rcParams["axes.prop_cycle"].by_key()["color"]
    for c, tr in enumerate(traces):
        t = np.asarray(tr.time, dtype=float)
        ax_u, ax_m = axes[len(groups), c], axes[-1, c]
        ages = getattr(tr, "ages", None)
        if has_ages and ages is not None and _network_run(tr):
            ages = np.asarray(ages, dtype=float)[:len(t) - 1]
            axes[-2, c].stairs(ages, t[:ages.size + 1], baseline=None, color="tab:green",
                               label="buffer age k - stamp (K_{age+1} applied)")
        m = tr.input.shape[1]
        for g, members in enumerate(groups):
            for i in members:
                label = family.state_label(i) if family is not None else f"x{i + 1}"
                axes[g, c].plot(t, tr.state[:, i], color=colors[i % len(colors)], label=label)
                if getattr(tr, "estimate", None) is not None:  # output feedback: the controller's estimate
                    axes[g, c].plot(t, tr.estimate[:, i], color=colors[i % len(colors)], linestyle="--",
                                    linewidth=1.0, label=f"{label}, estimate")
        for j in range(m):
            label = family.input_label(j) if family is not None else f"u{j + 1}"
            ax_u.stairs(tr.input[:, j], t, baseline=None, color=colors[(n + j) % len(colors)], label=label,
                        zorder=3)
        ax_m.stairs(np.asarray(tr.mode, dtype=float), t, baseline=None, color="0.2", label="plant mode")
        lost = np.flatnonzero(~np.asarray(tr.effective, dtype=bool))
        ax_m.plot(t[lost], np.full(lost.size, -1.0), "|", color="tab:red", markersize=7, markeredgewidth=1.2,
                  label="packet lost (buffer plays K_q, q > 1)")
        k = tr.settling_samples() if hasattr(tr, "settling_samples") else None
        title = titles[c] if titles else f"run {c + 1}"
        if k is not None:
            title += f"\nsettled to 2 % of |x(0)| at {t[k]:.3g} {'s' if timed else 'samples'}"
        axes[0, c].set_title(title, fontsize="medium")
        for ax in axes[:, c]:
            ax.grid(True, alpha=0.3)
            ax.set_xlim(float(t[0]), end)
            if k is not None and ax is not ax_m:
                ax.axvline(t[k], color="0.3", linestyle=":", linewidth=1,
                           label="settled (2 %)" if ax is ax_u else "_settled")
            if settling is not None and ax is not ax_m and settling <= end:
                ax.axvline(settling, color="tab:purple", linestyle="--", linewidth=1,
                           label="certified settling (worst case)" if ax is ax_u else "_certified")
        for j, limit in enumerate([] if u_max is None else np.atleast_1d(np.asarray(u_max, dtype=float))):
            for sign in (1.0, -1.0):
                ax_u.axhline(sign * limit, color=colors[(n + j) % len(colors)], linewidth=0.9, linestyle="--",
                             label=f"u_max = {limit:g}" if sign > 0 else None)
        ax_m.set_xlabel("time (s)" if timed else "sample k")
        if c == 0:
            for g, members in enumerate(groups):
                unit = (family.units or {}).get(family.state_names[members[0]]) if (
                    family is not None and family.state_names and family.units) else None
                axes[g, 0].set_ylabel(f"state ({unit})" if unit and len(members) > 1 else
                                      (family.state_label(members[0]) if family is not None else f"x{members[0] + 1}"))
                axes[g, 0].legend(loc="upper right", fontsize="small")
            ax_u.set_ylabel("input")
            ax_m.set_ylabel("network")
            if has_ages:
                axes[-2, 0].set_ylabel("age (samples)")
                axes[-2, 0].legend(loc="upper right", fontsize="small")
            ax_u.legend(loc="upper right", fontsize="small")
    names = getattr(family, "mode_names", None) if family is not None else None
    for ax in axes[-1]:
        ax.set_yticks([-1] + list(range(n_modes)),
                      ["lost"] + [names[l] if names else f"mode {l}" for l in range(n_modes)], fontsize="small")
        ax.set_ylim(-1.7, n_modes - 0.4)
    if traces:  # the strip's legend below the figure, where it covers nothing
        fig.legend(*axes[-1, 0].get_legend_handles_labels(), loc="outside lower center", ncols=2,
                   fontsize="small", frameon=False)
    _fit_rows(axes, end)
    return fig


def _network_run(tr) -> bool:
    """A run whose ages came from a network or replayed deliveries (on the paper's network they add nothing)."""
    if getattr(tr, "ages", None) is None:
        return False
    raw = getattr(tr, "raw", None) or {}
    loss_model = getattr(tr, "loss_model", None) or raw.get("loss_model")
    return (getattr(tr, "network", None) or raw.get("network")) is not None or loss_model in ("network", "arrivals")


def _fit_rows(axes, end: float) -> None:
    """Y-limits of the state and input rows from the data inside the shown window (shared by the row)."""
    for row in range(axes.shape[0] - 1):
        lo, hi = np.inf, -np.inf
        for ax in axes[row]:
            for line in ax.lines:
                x, y = (np.asarray(v, dtype=float) for v in line.get_data())
                if np.ptp(x) == 0:  # a vertical marker line (settling), not data
                    continue
                keep = y[x <= end]
                if keep.size:
                    lo, hi = min(lo, keep.min()), max(hi, keep.max())
            for patch in ax.patches:  # stairs
                vals = np.asarray(patch.get_data().values, dtype=float)
                edges = np.asarray(patch.get_data().edges, dtype=float)
                keep = vals[edges[:-1] <= end]
                if keep.size:
                    lo, hi = min(lo, keep.min()), max(hi, keep.max())
        if np.isfinite(lo) and np.isfinite(hi):
            pad = 0.08 * (hi - lo) if hi > lo else max(abs(hi), 1.0) * 0.1
            axes[row, 0].set_ylim(lo - pad, hi + pad + 0.25 * (hi - lo))  # room for the legend


def margin_figure(result: MarginResult, width: float = 8.0, height: float = 4.5, dpi: int = 100) -> Figure:
    """Max spectral radius of the designed loop at every point a margin search or grid tried.

    The points are drawn as markers, not joined: a bisection samples sparsely and in no order, so a
    line between them would suggest a measured curve.  Green dots: a stabilizing design was
    found, at its radius; red crosses: gains without a certificate, at their radius; points without
    gains (infeasible, solver failed, not converged) have no radius and are drawn as markers in a band
    at the bottom of the axes, each kind with its own marker and words.
    """
    fig = Figure(figsize=(width, height), dpi=dpi, layout="constrained")
    ax = fig.subplots()
    key = "n_drop" if result.kind == "n_drop" else "sampling_period"
    pts = sorted(result.curve, key=lambda p: (p.get(key), p.get("n_drop", 0)))
    xs = np.array([p[key] for p in pts], dtype=float)
    ys = np.array([np.nan if p.get("max_spectral_radius") is None else p["max_spectral_radius"] for p in pts])
    ok = np.array([p["outcome"] == "stabilized" for p in pts], dtype=bool)
    measured = ~np.isnan(ys)
    if ok.any():
        ax.plot(xs[ok & measured], ys[ok & measured], "o", color="tab:green", linestyle="none",
                label="stabilizing design found", zorder=3)
    if (~ok & measured).any():  # gains without a certificate: their radius is a measurement
        ax.plot(xs[~ok & measured], ys[~ok & measured], "x", color="tab:red", linestyle="none", markersize=8,
                label="design without certificate", zorder=3)
    # no gains, so no radius: drawn in a band at the bottom (x in data, y in axes units), never as a value
    band = ax.get_xaxis_transform()
    banded = False
    for outcome, marker, color, label in (
            ("infeasible", "v", "tab:red", "no design (infeasible at this point)"),
            ("solver_failed", "D", "tab:orange", "no certified design (solver failed: no proof)"),
            ("not_converged", "s", "tab:gray", "no certified design (not converged)")):
        sel = np.array([p["outcome"] == outcome for p in pts], dtype=bool) & ~measured
        if sel.any():
            ax.plot(xs[sel], np.full(sel.sum(), 0.04), marker, color=color, linestyle="none", markersize=7,
                    transform=band, label=label, zorder=3, clip_on=False)
            banded = True
    ax.axhline(1.0, color="k", linewidth=0.8, linestyle="--", label="spectral radius 1 (stability limit)")
    if result.margin is not None:
        text = (f"largest n_drop with a design: {int(result.margin)}" if result.kind == "n_drop"
                else f"largest h with a design: {float(result.margin):.4g} s")
        if ok.all():
            text += " (none failed up to the search limit)"
        ax.axvline(float(result.margin), color="tab:blue", linewidth=1, label=text)
    ax.set_xlabel({"n_drop": "n_drop (at most n_drop - 1 consecutive losses)",
                   "sampling_period": "sampling period h (s)",
                   "grid": "sampling period h (s)"}[result.kind])
    if result.kind == "n_drop":
        ax.xaxis.get_major_locator().set_params(integer=True)
    ax.set_ylabel("max spectral radius of the designed loop")
    what = {"n_drop": "largest drop bound", "sampling_period": "largest sampling period",
            "grid": "design grid"}[result.kind]
    ax.set_title(f"{what}, {result.method} design: {len(pts)} designs tried")
    ax.grid(True, alpha=0.3)
    if banded:  # keep the band (bottom 8 % of the axes) clear of measured radii
        lo, hi = ax.get_ylim()
        ax.set_ylim(lo - 0.12 * (hi - lo), hi)
        ax.fill_between([0, 1], 0, 0.08, transform=ax.transAxes, color="0.93", zorder=0, linewidth=0)
    ax.legend(loc="best", fontsize="small")
    return fig


def render(fig: Figure, fmt: str) -> bytes:
    """Encode a figure as ``"svg"`` or ``"png"`` bytes."""
    if fmt not in MEDIA_TYPES:
        raise ValueError(f"format must be one of {sorted(MEDIA_TYPES)}")
    buf = io.BytesIO()
    # A fixed hash salt and no date metadata keep the SVG byte-identical for identical data.
    metadata = {"Date": None} if fmt == "svg" else {"Software": None}
    with matplotlib.rc_context({"svg.hashsalt": "ncs-design"}):
        fig.savefig(buf, format=fmt, metadata=metadata)
    return buf.getvalue()


def channel_figure(channel, n_drops: Sequence[int], sampling_period: float | None = None,
                   sweep: Sequence[dict] | None = None, width: float = 10.0, height: float = 4.0,
                   dpi: int = 100) -> Figure:
    """How often a channel breaks the drop bound, and what losses cost the loop.

    Left: burst rate (runs of ``>= n_drop`` lost samples) per hour when ``sampling_period`` is
    given (per sample otherwise) against ``n_drop``, log scale.  Right (when ``sweep`` rows from
    :func:`solver.channel.loss_sweep` are given): expected cost against the Bernoulli loss
    probability, one line per exhaustion policy; losses without a mean-square stability proof
    are marked at the top edge.
    """
    fig = Figure(figsize=(width, height), dpi=dpi, layout="constrained")
    axes = fig.subplots(1, 2 if sweep else 1, squeeze=False)[0]
    ns = np.array(sorted(int(n) for n in n_drops))
    rates = np.array([channel.burst_rate(int(n)) for n in ns])
    per = "per sample"
    if sampling_period is not None:
        rates = rates / float(sampling_period) * 3600.0
        per = "per hour"
    ax = axes[0]
    shown = rates > 0
    ax.semilogy(ns[shown], rates[shown], "o-", color="tab:blue")
    ax.set_xlabel("n_drop (the buffer covers n_drop - 1 consecutive losses)")
    ax.set_ylabel(f"bursts of >= n_drop losses {per}")
    ax.xaxis.get_major_locator().set_params(integer=True)
    ax.set_title(f"drop-bound violations, loss fraction {channel.loss_fraction:.3g}")
    ax.grid(True, which="both", alpha=0.3)
    if sweep:
        ax = axes[1]
        for ex, color in (("hold", "tab:orange"), ("zero", "tab:green")):
            rows = sorted((r for r in sweep if r["exhausted"] == ex), key=lambda r: r["loss"])
            if not rows:
                continue
            ps = np.array([r["loss"] for r in rows])
            cost = np.array([np.nan if r["expected_cost"] is None else r["expected_cost"] for r in rows])
            ax.plot(ps, cost, "o-", color=color, label=f"exhausted = {ex}")
            bad = np.isnan(cost)
            if bad.any():
                top = np.nanmax(cost) if np.isfinite(cost).any() else 1.0
                ax.plot(ps[bad], np.full(bad.sum(), top), "x", color=color, markersize=8,
                        label=f"{ex}: not proven mean-square stable")
        ax.set_xlabel("Bernoulli loss probability")
        ax.set_ylabel("expected cost  E sum x'Qx + u'Ru")
        ax.set_title("expected cost, E x(0) x(0)' = I")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize="small")
    return fig
