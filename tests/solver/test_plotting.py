import io

import numpy as np
import pytest
from PIL import Image

from solver import PlantFamily, simulate
from solver.margins import max_n_drop
from solver.plotting import margin_figure, render, trace_figure

from .paper_data import EQ23_GAINS

FAM = PlantFamily.paper_example(0.1)


def traces():
    return [simulate(FAM, EQ23_GAINS, 3, x0=[-3, 2], steps=40, seed=42, plant_switching="none", mode=l)
            for l in range(3)]


def test_trace_png_decodes_with_the_requested_size():
    png = render(trace_figure(traces(), ["J = 0.03", "J = 0.02", "J = 0.01"], width=9, height=5, dpi=80), "png")
    img = Image.open(io.BytesIO(png))
    img.load()
    assert img.format == "PNG" and img.size == (9 * 80, 5 * 80)
    # not a blank canvas: the curves put many distinct colours on it
    assert len({tuple(px) for px in np.asarray(img.convert("RGB")).reshape(-1, 3)[::97].tolist()}) > 20


def test_trace_svg_is_deterministic_and_marks_losses():
    a = render(trace_figure(traces()), "svg")
    b = render(trace_figure(traces()), "svg")
    assert a == b and a.startswith(b"<?xml")
    assert b"lost" in a


def test_margin_curve_plot():
    res = max_n_drop(FAM, "lmi", n_drop_max=3)
    png = render(margin_figure(res, width=6, height=4, dpi=50), "png")
    assert Image.open(io.BytesIO(png)).size == (300, 200)


def test_trace_figure_names_units_modes_losses_shared_axes_and_window():
    from solver.plotting import default_window, settling_time

    fam = PlantFamily.dc_motor([0.03, 0.05], 0.1)
    gains = [[[-4.12, 0.29]], [[0.066, -0.009]], [[0.0099, 0.038]]]
    runs = [simulate(fam, gains, 3, x0=[1.0, -1.0], steps=80, seed=3)]
    runs += [simulate(fam, gains, 3, x0=[1.0, -1.0], steps=80, seed=3, plant_switching="none", mode=1)]
    fig = trace_figure(runs, ["switching", "mode 1"], family=fam)
    axes = np.array(fig.axes).reshape(3, 2)
    labels = [t.get_text() for t in axes[0, 0].get_legend().get_texts()]
    assert labels == ["i_a (A)", "omega (rad/s)"]
    assert [t.get_text() for t in axes[1, 0].get_legend().get_texts()] == ["v_a (V)"]
    assert [t.get_text() for t in fig.legends[0].get_texts()] == ["plant mode", "packet lost (buffer plays K_q, q > 1)"]
    assert axes[2, 0].get_xlabel() == "time (s)"
    for row in range(3):  # one y-range per row across the columns
        assert axes[row, 0].get_ylim() == axes[row, 1].get_ylim()
    # every state value inside the window is inside the y-range
    lo, hi = axes[0, 0].get_ylim()
    end = axes[0, 0].get_xlim()[1]
    for tr in runs:
        shown = tr.state[tr.time <= end]
        assert lo <= shown.min() and shown.max() <= hi
    # the window fits the transient: |x| under 1e-3 of its peak before its end, well before the 8 s run ends
    norm = np.linalg.norm(runs[0].state, axis=1)
    assert np.all(norm[runs[0].time >= end] < 1e-3 * norm.max())
    assert end == default_window(runs) and 0.5 < end < 8.0
    assert end == pytest.approx(max(1.2 * max(settling_time(tr) for tr in runs), 1.0))
    # the active plant mode is drawn (a step trace of tr.mode) and the losses as ticks on their own row
    stairs = axes[2, 0].patches[0]
    np.testing.assert_array_equal(stairs.get_data().values, runs[0].mode)
    ticks = [ln for ln in axes[2, 0].lines if ln.get_marker() == "|"][0]
    np.testing.assert_allclose(ticks.get_xdata(), runs[0].time[:-1][~runs[0].effective])
    assert set(np.asarray(ticks.get_ydata())) == {-1.0} and min(axes[2, 0].get_ylim()) < -1
    assert [t.get_text() for t in axes[2, 0].get_yticklabels()] == ["lost", "mode 0", "mode 1"]


def test_margin_figure_draws_points_not_a_line_with_units():
    from solver.margins import MarginResult

    curve = [{"sampling_period": h, "n_drop": 3, "outcome": "stabilized" if h < 0.5 else "infeasible",
              "max_spectral_radius": 0.9 if h < 0.5 else None} for h in (0.01, 1.0, 0.5, 0.25, 0.375)]
    fig = margin_figure(MarginResult(kind="sampling_period", margin=0.375, design=None, curve=curve))
    ax = fig.axes[0]
    assert ax.get_xlabel() == "sampling period h (s)"
    points = [ln for ln in ax.lines if ln.get_marker() not in ("None", None, "")]
    assert sum(len(ln.get_xdata()) for ln in points) == 5 and all(ln.get_linestyle() == "None" for ln in points)
    for ln in ax.lines:  # everything else is a horizontal or vertical reference line
        if ln not in points:
            assert np.ptp(np.asarray(ln.get_xdata(), float)) == 0 or np.ptp(np.asarray(ln.get_ydata(), float)) == 0
    texts = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "largest h with a design: 0.375 s" in texts and "no stabilizing design" in texts
