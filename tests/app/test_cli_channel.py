"""``ncs-design channel``: a subprocess run on the paper's motor over a Gilbert-Elliott link."""

import json

from solver import Channel, PlantFamily, analyze_channel, design

from .test_cli import ncs


def test_channel_command_reports_bursts_stability_and_cost(tmp_path):
    (tmp_path / "plant.json").write_text(json.dumps(
        {"kind": "dc_motor", "inertias": [0.03, 0.05], "sampling_period": 0.1}))
    fam = PlantFamily.dc_motor([0.03, 0.05], 0.1)
    K = design(fam, 3).gains
    (tmp_path / "gains.json").write_text(json.dumps(K.tolist()))
    out = ncs("channel", "plant.json", "--gains", "gains.json", "--gilbert-elliott", "0.05,0.3,0.01,0.8",
              "--exhausted", "zero", "--target-per-hour", "1", "--output", "rep.json", "--plot", "ch.svg",
              cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    ref = analyze_channel(fam, K, 3, Channel.gilbert_elliott(0.05, 0.3, 0.01, 0.8), exhausted="zero")
    assert f"{ref.burst_rate / 0.1 * 3600:.4g} per hour" in out.stdout
    assert "mean-square stable (certified)" in out.stdout and "smallest n_drop" in out.stdout
    rep = json.loads((tmp_path / "rep.json").read_text())
    assert rep["ms_stable"] is True and rep["expected_cost"] > 0
    assert (tmp_path / "ch.svg").read_bytes().startswith(b"<?xml")
    bad = ncs("channel", "plant.json", "--gains", "gains.json", "--gilbert-elliott", "0.05,0.3", cwd=tmp_path)
    assert bad.returncode == 2 and "four numbers" in bad.stderr
    bad = ncs("channel", "plant.json", "--gains", "gains.json", "--loss", "1.5", cwd=tmp_path)
    assert bad.returncode == 2 and "(loss)" in bad.stderr


def test_channel_command_designs_for_the_channel(tmp_path):
    (tmp_path / "plant.json").write_text(json.dumps(
        {"kind": "dc_motor", "inertias": [0.03, 0.05], "sampling_period": 0.1}))
    out = ncs("channel", "plant.json", "--design", "--n-drop", "3", "--loss", "0.3", "--exhausted", "zero",
              "--output", "d.json", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert "channel design, n_drop = 3: stabilized" in out.stdout and "K_3 = " in out.stdout
    data = json.loads((tmp_path / "d.json").read_text())
    fam = PlantFamily.dc_motor([0.03, 0.05], 0.1)
    ref = analyze_channel(fam, data["gains"], 3, Channel.bernoulli(0.3), exhausted="zero")
    assert data["analysis"]["ms_stable"] is True and ref.ms_stable is True
    assert ncs("channel", "plant.json", "--loss", "0.3", cwd=tmp_path).returncode == 2
