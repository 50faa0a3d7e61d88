import io

import numpy as np
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
