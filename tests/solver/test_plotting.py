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
    fam = PlantFamily.dc_motor([0.03, 0.05], 0.1)
    gains = [[[-4.12, 0.29]], [[0.066, -0.009]], [[0.0099, 0.038]]]
    runs = [simulate(fam, gains, 3, x0=[1.0, -1.0], steps=80, seed=3)]
    runs += [simulate(fam, gains, 3, x0=[1.0, -1.0], steps=80, seed=3, plant_switching="none", mode=1)]
    fig = trace_figure(runs, ["switching", "mode 1"], family=fam)
    axes = np.array(fig.axes).reshape(4, 2)  # A and rad/s: one state axis per unit, inputs, strip
    assert [t.get_text() for t in axes[0, 0].get_legend().get_texts()] == ["i_a (A)"]
    assert [t.get_text() for t in axes[1, 0].get_legend().get_texts()] == ["omega (rad/s)"]
    assert [t.get_text() for t in axes[2, 0].get_legend().get_texts()][0] == "v_a (V)"
    assert [t.get_text() for t in fig.legends[0].get_texts()] == ["plant mode", "packet lost (buffer plays K_q, q > 1)"]
    assert axes[3, 0].get_xlabel() == "time (s)"
    for row in range(4):  # one y-range per row across the columns
        assert axes[row, 0].get_ylim() == axes[row, 1].get_ylim()
    # the whole simulated window (8 s), every state value inside its axis' y-range
    for ax in axes.ravel():
        assert ax.get_xlim() == (0.0, pytest.approx(8.0))
    for row, i in ((0, 0), (1, 1)):
        lo, hi = axes[row, 0].get_ylim()
        for tr in runs:
            assert lo <= tr.state[:, i].min() and tr.state[:, i].max() <= hi
    # the active plant mode is drawn (a step trace of tr.mode) and the losses as ticks on their own row
    stairs = axes[3, 0].patches[0]
    np.testing.assert_array_equal(stairs.get_data().values, runs[0].mode)
    ticks = [ln for ln in axes[3, 0].lines if ln.get_marker() == "|"][0]
    np.testing.assert_allclose(ticks.get_xdata(), runs[0].time[:-1][~runs[0].effective])
    assert set(np.asarray(ticks.get_ydata())) == {-1.0} and min(axes[3, 0].get_ylim()) < -1
    # the plant's mode names (dc_motor: its inertias), not code words
    assert [t.get_text() for t in axes[3, 0].get_yticklabels()] == ["lost", "J = 0.03 kg m^2", "J = 0.05 kg m^2"]


def test_trace_figure_one_axis_per_unit_group_full_window_and_whole_input():
    """Issue 22, item 7: cart-pole states in m, m/s, rad, rad/s each get an axis; without units, one axis per
    state; the x-range is the simulated window unless t_max asks for less; the input covers the whole window
    and no zero reference line is drawn where data could be expected."""
    from .cartpole import cartpole

    fam = cartpole()
    gains = [[[15.0, 13.8, 62.2, 10.8]], [[7.1, 6.8, 37.3, 6.6]], [[3.7, 4.0, 28.5, 5.2]]]
    run = simulate(fam, gains, 3, x0=[0, 0, 0.1, 0], steps=300, seed=42)
    fig = trace_figure([run], ["Plant may switch when a packet arrives"], family=fam, settling=5.04)
    assert len(fig.axes) == 4 + 2
    for ax in fig.axes:
        assert ax.get_xlim() == (0.0, pytest.approx(6.0))
    input_ax = fig.axes[4]
    stairs = input_ax.patches[0].get_data()
    assert len(stairs.values) == 300 and stairs.edges[0] == 0.0 and stairs.edges[-1] == pytest.approx(6.0)
    np.testing.assert_array_equal(stairs.values, run.input[:, 0])
    for ax in fig.axes[:5]:  # data lines span the run; the only other lines are vertical markers
        for line in ax.lines:
            x = np.asarray(line.get_xdata(), dtype=float)
            assert len(x) == 301 or np.ptp(x) == 0, line.get_label()
    assert "theta (rad)" == fig.axes[2].get_ylabel()
    # without names and units: one axis per state; a shorter window only on request
    bare = PlantFamily(F=fam.F, G=fam.G, sampling_period=0.02)
    fig = trace_figure([run], family=bare, t_max=2.0)
    assert len(fig.axes) == 4 + 2 and fig.axes[0].get_xlim() == (0.0, 2.0)
    fig = trace_figure([run], family=PlantFamily(F=fam.F, G=fam.G, sampling_period=0.02,
                                                  state_names=["a", "b", "c", "d"], units={n: "m" for n in "abcd"}))
    assert len(fig.axes) == 1 + 2  # all four in m share one axis


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
    assert "largest h with a design: 0.375 s" in texts and "no design (infeasible at this point)" in texts


def test_failed_margin_probes_are_drawn_as_what_they_are_not_at_radius_one():
    from solver.margins import MarginResult

    curve = [{"sampling_period": 0.005, "outcome": "stabilized", "max_spectral_radius": 0.996},
             {"sampling_period": 1.0, "outcome": "solver_failed", "max_spectral_radius": None},
             {"sampling_period": 0.5, "outcome": "infeasible", "max_spectral_radius": None},
             {"sampling_period": 0.25, "outcome": "stabilized", "max_spectral_radius": 0.97}]
    fig = margin_figure(MarginResult(kind="sampling_period", margin=0.25, design=None, curve=curve))
    ax = fig.axes[0]
    texts = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "no certified design (solver failed: no proof)" in texts and "no design (infeasible at this point)" in texts
    for line in ax.lines:
        label = line.get_label()
        if label.startswith("no "):  # placed in axes units (a band), not at a spectral radius
            assert line.get_transform() != ax.transData
            assert set(np.asarray(line.get_ydata(), float)) == {0.04}
        elif line.get_marker() == "o":
            assert sorted(np.asarray(line.get_ydata(), float)) == [0.97, 0.996]
    assert "mode" not in ax.get_title() and "_" not in ax.get_title()
