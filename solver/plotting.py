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


def trace_figure(traces: Sequence[SimulationResult], titles: Sequence[str] | None = None,
                 width: float = 10.0, height: float = 6.0, dpi: int = 100, family=None) -> Figure:
    """States and inputs over time for each run, lost samples marked.

    Parameters
    ----------
    traces : sequence of SimulationResult
    titles : sequence of str, optional
    width, height : float
        Figure size in inches (pixels = inches * dpi for PNG).
    """
    cols = max(len(traces), 1)
    fig = Figure(figsize=(width, height), dpi=dpi, layout="constrained")
    axes = fig.subplots(2, cols, sharex="col", squeeze=False)
    for c, tr in enumerate(traces):
        t = tr.time
        ax_x, ax_u = axes[0, c], axes[1, c]
        for i in range(tr.state.shape[1]):
            ax_x.plot(t, tr.state[:, i], label=f"x{i + 1}")
        for j in range(tr.input.shape[1]):
            ax_u.step(t[:-1], tr.input[:, j], where="post", label=f"u{j + 1}")
        lost = np.flatnonzero(~tr.effective)
        if lost.size:
            ax_u.plot(t[lost], np.zeros(lost.size), "x", color="tab:red", markersize=4, label="lost")
            for ax in (ax_x, ax_u):
                for k in lost:
                    ax.axvspan(t[k], t[k + 1], color="tab:red", alpha=0.08, linewidth=0)
        ax_x.set_title(titles[c] if titles else f"run {c + 1}")
        ax_x.grid(True, alpha=0.3)
        ax_u.grid(True, alpha=0.3)
        ax_u.set_xlabel("time (s)" if tr.time[1] != 1.0 else "sample")
        if c == 0:
            ax_x.set_ylabel("state")
            ax_u.set_ylabel("input")
        ax_x.legend(loc="upper right", fontsize="small")
        ax_u.legend(loc="upper right", fontsize="small")
    return fig


def margin_figure(result: MarginResult, width: float = 8.0, height: float = 4.5, dpi: int = 100) -> Figure:
    """Max spectral radius (and stabilized or not) over the points a margin search or grid tried."""
    fig = Figure(figsize=(width, height), dpi=dpi, layout="constrained")
    ax = fig.subplots()
    key = "n_drop" if result.kind == "n_drop" else "sampling_period"
    pts = sorted(result.curve, key=lambda p: (p.get(key), p.get("n_drop", 0)))
    xs = np.array([p[key] for p in pts], dtype=float)
    ys = np.array([np.nan if p["max_spectral_radius"] is None else p["max_spectral_radius"] for p in pts])
    ok = np.array([p["outcome"] == "stabilized" for p in pts])
    if result.kind != "grid":
        ax.plot(xs, ys, "-", color="0.6", zorder=1)
    ax.scatter(xs[ok], np.where(np.isnan(ys[ok]), 0, ys[ok]), color="tab:green", label="stabilized", zorder=2)
    ax.scatter(xs[~ok], np.where(np.isnan(ys[~ok]), 1, ys[~ok]), color="tab:red", marker="x",
               label="no design", zorder=2)
    ax.axhline(1.0, color="k", linewidth=0.8, linestyle="--")
    if result.margin is not None:
        ax.axvline(float(result.margin), color="tab:blue", linewidth=1, label=f"margin {result.margin:g}")
    ax.set_xlabel({"n_drop": "n_drop", "sampling_period": "sampling period h (s)",
                   "grid": "sampling period h (s)"}[result.kind])
    ax.set_ylabel("max spectral radius of the designed loop")
    ax.set_title(f"{result.kind} search, method {result.method}")
    ax.grid(True, alpha=0.3)
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
