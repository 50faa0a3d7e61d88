"""MATLAB/Octave out (.mat, .m) and in (plant .mat files), read back with scipy, a strict reader and Octave."""

import io
import re
import shutil
import subprocess

import numpy as np
import pytest
import scipy.io

from solver import InvalidInput, PlantFamily, design
from solver.matlab import m_script, mat_bytes, matlab_variables, plant_from_mat, save_mat


@pytest.fixture(scope="module")
def designed():
    fam = PlantFamily.dc_motor([0.03, 0.05], 0.1)
    return fam, design(fam, 3)


def read_m_script(text: str) -> dict:
    """A strict reader of the scripts m_script writes: comments, and `name = literal;` lines only."""
    number = r"[-+]?(?:\d+\.?\d*(?:[eE][-+]?\d+)?|Inf|NaN)"
    out = {}
    for line in text.splitlines():
        if not line or line.startswith("%"):
            continue
        m = re.fullmatch(r"(\w+) = (.*);", line)
        assert m, f"unexpected line {line!r}"
        name, lit = m.groups()
        if lit.startswith("'"):
            assert re.fullmatch(r"'(?:[^']|'')*'", lit)
            out[name] = lit[1:-1].replace("''", "'")
        elif lit.startswith("reshape("):
            m2 = re.fullmatch(rf"reshape\(\[((?:{number} ?)+)\], \[([\d ]+)\]\)", lit)
            assert m2, lit
            vals = np.array([float(v) for v in m2.group(1).split()])
            out[name] = vals.reshape([int(d) for d in m2.group(2).split()], order="F")
        elif lit == "[]":
            out[name] = np.zeros((0, 0))
        elif lit.startswith("["):
            rows = lit[1:-1].split("; ")
            out[name] = np.array([[float(v) for v in row.split(" ")] for row in rows])
        else:
            assert re.fullmatch(number, lit), lit
            out[name] = float(lit)
    return out


def test_mat_file_reads_back_with_scipy(designed, tmp_path):
    fam, res = designed
    path = tmp_path / "gains.mat"
    save_mat(path, res, fam)
    d = scipy.io.loadmat(path)
    assert d["K"].shape == (3, 1, 2)
    np.testing.assert_array_equal(d["K"], res.gains)
    for q in range(3):
        np.testing.assert_array_equal(d[f"K{q + 1}"], res.gains[q])
    for l in range(2):  # MATLAB convention F(:,:,l)
        np.testing.assert_array_equal(d["F"][:, :, l], fam.F[l])
        np.testing.assert_array_equal(d["G"][:, :, l], fam.G[l])
    np.testing.assert_array_equal(d["P"], res.certificate.P)
    assert d["P"].shape == (6, 6)
    assert int(d["n_drop"][0, 0]) == 3 and str(d["outcome"][0]) == "stabilized"
    assert str(d["certificate"][0]) == "common_quadratic" and float(d["h"][0, 0]) == 0.1
    # The written file is itself a plant file.
    back = plant_from_mat(path)
    np.testing.assert_array_equal(back.F, fam.F)
    assert back.sampling_period == 0.1


def test_service_json_result_gives_the_same_file(designed):
    fam, res = designed
    service = {**res.to_dict(), "F": fam.F.tolist(), "G": fam.G.tolist(), "sampling_period": 0.1}
    a = scipy.io.loadmat(io.BytesIO(mat_bytes(service)))
    b = scipy.io.loadmat(io.BytesIO(mat_bytes(res, fam)))
    for key in ("K", "K1", "F", "G", "P", "n_drop"):
        np.testing.assert_array_equal(a[key], b[key])
    with pytest.raises(InvalidInput) as err:
        matlab_variables(res)
    assert err.value.field == ("family",)


def test_infeasible_result_has_no_gains_and_empty_certificate():
    res = {"outcome": "infeasible", "n_drop": 2, "gains": None, "certificate": None,
           "F": [[[2.0]]], "G": [[[0.0]]], "sampling_period": None}
    v = matlab_variables(res)
    assert v["outcome"] == "infeasible" and "K1" not in v and v["P"].size == 0 and v["certificate"] == ""
    parsed = read_m_script(m_script(res))
    assert parsed["P"].size == 0 and parsed["outcome"] == "infeasible"


def test_m_script_defines_the_same_values_bit_for_bit(designed):
    fam, res = designed
    parsed = read_m_script(m_script(res, fam, name="job 42"))
    np.testing.assert_array_equal(parsed["K"], res.gains)
    np.testing.assert_array_equal(parsed["K2"], res.gains[1])
    np.testing.assert_array_equal(parsed["F"], np.moveaxis(fam.F, 0, -1))
    np.testing.assert_array_equal(parsed["P"], res.certificate.P)
    assert parsed["outcome"] == "stabilized" and parsed["n_drop"] == 3.0 and parsed["h"] == 0.1


@pytest.mark.skipif(shutil.which("octave") is None, reason="octave is not installed (apt-get install octave)")
def test_octave_runs_the_script_and_reads_the_mat_file(designed, tmp_path):
    fam, res = designed
    (tmp_path / "gains.m").write_text(m_script(res, fam))
    save_mat(tmp_path / "gains.mat", res, fam)
    code = ("gains; s = load('gains.mat'); "
            "printf('%.17g ', K2, squeeze(K(3,:,:)), F(:,:,2), s.K(:) - K(:), s.P(:) - P(:)); "
            "printf('\\n%s %d %s\\n', outcome, n_drop, s.outcome);")
    out = subprocess.run(["octave", "--no-gui", "--no-window-system", "-q", "--eval", code], cwd=tmp_path,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    nums_line, words = out.stdout.strip().splitlines()[-2:]
    nums = np.array([float(v) for v in nums_line.split()])
    np.testing.assert_array_equal(nums[:2], res.gains[1].ravel())
    np.testing.assert_array_equal(nums[2:4], res.gains[2].ravel())
    np.testing.assert_array_equal(nums[4:8], fam.F[1].ravel(order="F"))
    assert np.all(nums[8:] == 0)
    assert words.split() == ["stabilized", "3", "stabilized"]


def test_plant_mat_files_cell_arrays_3d_and_continuous(tmp_path):
    fam = PlantFamily.paper_example(0.1)
    cells = np.empty((1, 3), dtype=object)
    for l in range(3):
        cells[0, l] = fam.A[l]
    bcells = np.empty((1, 3), dtype=object)
    for l in range(3):
        bcells[0, l] = fam.B[l]
    scipy.io.savemat(tmp_path / "cells.mat", {"A": cells, "B": bcells, "h": 0.1})
    got = plant_from_mat(tmp_path / "cells.mat")
    np.testing.assert_allclose(got.F, fam.F, rtol=1e-14)
    scipy.io.savemat(tmp_path / "cube.mat", {"A": np.moveaxis(fam.A, 0, -1), "B": np.moveaxis(fam.B, 0, -1)})
    np.testing.assert_allclose(plant_from_mat(tmp_path / "cube.mat", sampling_period=0.1).G, fam.G, rtol=1e-14)
    with pytest.raises(InvalidInput, match="sampling-period") as err:
        plant_from_mat(tmp_path / "cube.mat")
    assert err.value.field == ("sampling_period",)
    scipy.io.savemat(tmp_path / "one.mat", {"F": fam.F[0], "G": fam.G[0]})
    assert plant_from_mat(tmp_path / "one.mat").n_modes == 1
    scipy.io.savemat(tmp_path / "none.mat", {"X": 1.0})
    with pytest.raises(InvalidInput, match=r"A and B .* F and G") as err:
        plant_from_mat(tmp_path / "none.mat")
    (tmp_path / "junk.mat").write_bytes(b"not a mat file")
    with pytest.raises(InvalidInput, match="not a readable .mat"):
        plant_from_mat(tmp_path / "junk.mat")
