"""The generated C on the review's and the target's tools: cppcheck's MISRA C:2012 addon, arm-none-eabi-gcc for
Cortex-M4 and M0+, the kit's CMake build and its replay test on the host and on an emulated Cortex-M (QEMU MPS2
with semihosting), compared with :func:`solver.simulate`.

Each test skips when its tool is missing (.ci/run installs cppcheck, gcc-arm-none-eabi, qemu-system-arm, cmake).
"""

from __future__ import annotations

import re
import shutil
import struct
import subprocess

import numpy as np
import pytest

from solver import PlantFamily, design, export_c, simulate
from solver.c_kit import export_kit

PAPER = PlantFamily.paper_example(0.1)
ARM_FLAGS = {"cortex-m4": ["-mcpu=cortex-m4", "-mthumb", "-mfloat-abi=hard", "-mfpu=fpv4-sp-d16"],
             "cortex-m0plus": ["-mcpu=cortex-m0plus", "-mthumb", "-mfloat-abi=soft"]}
STRICT = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic"]


def need(*tools):
    missing = [t for t in tools if shutil.which(t) is None]
    if missing:
        pytest.skip(f"not installed: {', '.join(missing)}")


def write(directory, files):
    for name, text in files.items():
        path = directory / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


@pytest.fixture(scope="module")
def paper_design():
    res = design(PAPER, 3, method="lmi")
    assert res.outcome == "stabilized"
    return res


def variants(paper_design):
    rng = np.random.default_rng(3)
    return [
        ("ncs", export_c(paper_design, 3, metadata={"id": "x */ ??/ %n"})),
        ("f32", export_c(paper_design, 3, prefix="f32", precision="float32", family=PAPER)),
        ("wide", export_c(rng.standard_normal((4, 3, 5)), 4, exhausted="zero", prefix="wide")),
        ("one", export_c(np.full((1, 1, 1), 0.5), 1, prefix="one")),  # every loop bound 1
    ]


def test_misra_c_2012_cppcheck_has_no_findings(tmp_path, paper_design):
    """cppcheck's MISRA addon on every variant (m = 1 and m > 1, hold and zero, float64 and float32): no finding."""
    need("cppcheck")
    sources = []
    for _, files in variants(paper_design):
        write(tmp_path, files)
        sources += [str(tmp_path / n) for n in files if n.endswith(".c")]
    out = subprocess.run(["cppcheck", "--addon=misra", "--enable=all", "--std=c99", "--error-exitcode=3",
                          "--suppress=missingIncludeSystem", "--suppress=unusedFunction", "--inline-suppr",
                          "--template={file}:{line}: {id}: {message}", "-q"] + sources,
                         capture_output=True, text=True, cwd=tmp_path)
    assert out.returncode == 0 and out.stderr.strip() == "", out.stderr
    # and the addon does report: a deliberate violation (rule 15.5, two returns) is found
    (tmp_path / "bad.c").write_text("int f(int a);\nint f(int a)\n{\n    if (a > 0) {\n        return 1;\n    }\n"
                                    "    return 0;\n}\n")
    bad = subprocess.run(["cppcheck", "--addon=misra", "--std=c99", "-q", str(tmp_path / "bad.c")],
                         capture_output=True, text=True)
    assert "misra-c2012-15.5" in bad.stderr


def test_no_library_calls_no_recursion_no_dynamic_stack(tmp_path, paper_design):
    """Host objects need no symbol at all; every function's stack is static (no recursion, no VLA, no alloca)."""
    for prefix, files in variants(paper_design):
        write(tmp_path, files)
        src = files[f"{prefix}_controller.c"] + files[f"{prefix}_controller.h"]
        assert set(re.findall(r"#include <([^>]+)>", src)) == {"stddef.h", "stdint.h"}
        assert not re.search(r"\b(malloc|calloc|realloc|free|alloca)\b", src)
        obj = tmp_path / f"{prefix}.o"
        subprocess.run(["gcc"] + STRICT + ["-O2", "-fstack-usage", "-c", "-o", str(obj),
                        str(tmp_path / f"{prefix}_controller.c")], check=True)
        undefined = subprocess.run(["nm", "-u", str(obj)], capture_output=True, text=True, check=True).stdout
        assert undefined.strip() == "", undefined
        usage = (tmp_path / f"{prefix}.su").read_text().strip().splitlines()
        assert usage and all(line.endswith("\tstatic") for line in usage), usage


def arm_object(tmp_path, files, prefix, cpu):
    write(tmp_path, files)
    obj = tmp_path / f"{prefix}-{cpu}.o"
    subprocess.run(["arm-none-eabi-gcc"] + ARM_FLAGS[cpu] + STRICT + ["-Os", "-ffunction-sections",
                    "-fstack-usage", "-c", "-o", str(obj), str(tmp_path / f"{prefix}_controller.c")], check=True,
                   cwd=tmp_path)
    size = subprocess.run(["arm-none-eabi-size", str(obj)], capture_output=True, text=True, check=True).stdout
    text, data, bss = (int(v) for v in size.splitlines()[1].split()[:3])
    undefined = subprocess.run(["arm-none-eabi-nm", "-u", str(obj)], capture_output=True, text=True,
                               check=True).stdout.split()
    stack = [int(line.split("\t")[1]) for line in (tmp_path / f"{prefix}-{cpu}.su").read_text().splitlines()]
    return text, data, bss, [u for u in undefined if u != "U"], max(stack)


@pytest.mark.parametrize("cpu", ["cortex-m4", "cortex-m0plus"])
def test_cortex_m_builds(tmp_path, paper_design, cpu):
    """-Os builds for Cortex-M4 (FPU) and M0+ (no FPU): no RAM in the object, only the compiler's float helpers."""
    need("arm-none-eabi-gcc", "arm-none-eabi-size", "arm-none-eabi-nm")
    for prefix, files in variants(paper_design):
        text, data, bss, undefined, stack = arm_object(tmp_path, files, prefix, cpu)
        assert text > 0 and data == 0 and bss == 0
        # libgcc's soft-float helpers, and <string.h>'s memset that gcc makes of the zeroing loops at -Os
        assert all(u.startswith("__aeabi_") or u in ("memset", "memcpy") for u in undefined), undefined
        if cpu == "cortex-m4" and prefix == "f32":
            assert not any(u.startswith("__aeabi_") for u in undefined)  # single precision runs on the FPU
        if cpu == "cortex-m0plus":
            assert any(u in undefined for u in ("__aeabi_dmul", "__aeabi_fmul"))  # no FPU: helpers
        assert 0 <= stack < 256


def run_qemu(elf, cpu):
    board = "mps2-an386" if cpu == "cortex-m4" else "mps2-an385"
    out = subprocess.run(["qemu-system-arm", "-M", board, "-nographic", "-monitor", "none", "-serial", "none",
                          "-semihosting-config", "enable=on,target=native", "-kernel", str(elf)],
                         capture_output=True, text=True, timeout=60)
    out.stdout += out.stderr  # QEMU writes semihosting output to stderr or stdout depending on its version
    return out


def cmake_build(src, build, *args):
    subprocess.run(["cmake", "-S", str(src), "-B", str(build), *args], check=True, capture_output=True, text=True)
    subprocess.run(["cmake", "--build", str(build)], check=True, capture_output=True, text=True)


def corrupt(data_file):
    """Move one reference input by 100 tolerances: the replay must now fail."""
    text = data_file.read_text()
    head, rest = text.split("_replay_input", 1)
    first = re.search(r"\{(-?[0-9.e+-]+)", rest)
    value = float(first.group(1))
    data_file.write_text(head + "_replay_input" + rest[:first.start(1)] + repr(value + 1e-3 + abs(value))
                         + rest[first.end(1):])


@pytest.mark.parametrize("cpu, precision", [("cortex-m4", "float32"), ("cortex-m4", "float64"),
                                            ("cortex-m0plus", "float64"), ("cortex-m0plus", "float32")])
def test_on_target_equivalence_with_simulate(tmp_path, paper_design, cpu, precision):
    """The kit cross-built with its toolchain file and run on an emulated board: every output, read back bit by
    bit over semihosting, equals simulate's input (float64: to float64 rounding; float32: within the float32 bound
    of the rounded gains); the on-target check passes, and fails once a reference value is corrupted."""
    need("arm-none-eabi-gcc", "qemu-system-arm", "cmake")
    steps = 120
    files = export_kit(paper_design, 3, family=PAPER, precision=precision, steps=steps, seed=4)
    write(tmp_path / "kit", files)
    cmake_build(tmp_path / "kit", tmp_path / "build", "-DCMAKE_TOOLCHAIN_FILE=cmake/arm-none-eabi.cmake",
                f"-DNCS_CPU={cpu}")
    elf = tmp_path / "build" / "ncs_replay_target.elf"
    out = run_qemu(elf, cpu)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "bad 00000000" in out.stdout
    rows = re.findall(r"^u ([0-9a-f]{8}) ([0-9a-f]{8}) ([0-9a-f]+)$", out.stdout, re.M)
    assert len(rows) == steps
    fmt, width = ("<f", 4) if precision == "float32" else ("<d", 8)
    u = np.array([struct.unpack(fmt, int(bits, 16).to_bytes(width, "little"))[0] for _, _, bits in rows])
    K = paper_design.gains if precision == "float64" else paper_design.gains.astype(np.float32).astype(float)
    # an independent run of simulate (the kit's data came from its own call)
    sim = simulate(PAPER, K, 3, x0=np.ones(2), steps=steps, seed=4, loss_model="bernoulli", sensor_loss=0.3,
                   control_loss=0.3)
    assert not np.all(sim.effective)
    sent = sim.state[:-1][np.maximum.accumulate(np.where(sim.effective, np.arange(steps), 0))]
    absK = np.abs(K[sim.buffer_index - 1, 0])  # (steps, n): the entry played, m = 1
    mag = np.einsum("kn,kn->k", absK, np.abs(sent))
    n = 2
    bound = 4 * (n + 1) * 2.0**-53 * mag + 1e-300  # float64 on both sides
    if precision == "float32":
        bound += (n + 1) * 2.0**-24 / (1 - (n + 1) * 2.0**-24) * mag + 2.0**-126 * (n + absK.sum(axis=1))
    assert np.all(np.abs(u - sim.input[:, 0]) <= bound)
    # the on-target comparison can fail
    corrupt(tmp_path / "kit" / "test" / "ncs_replay_data.c")
    subprocess.run(["cmake", "--build", str(tmp_path / "build")], check=True, capture_output=True)
    bad = run_qemu(elf, cpu)
    assert bad.returncode != 0 and "bad 00000001" in bad.stdout


def test_kit_host_replay_and_add_subdirectory(tmp_path, paper_design):
    """The kit's CMakeLists: the host replay test passes (and exits non-zero on a corrupted reference); a firmware
    project links the controller with add_subdirectory."""
    need("cmake", "gcc")
    rng = np.random.default_rng(11)
    fam = PlantFamily(F=[np.linalg.qr(rng.standard_normal((3, 3)))[0] * 1.02 for _ in range(2)],
                      G=[rng.standard_normal((3, 2)) for _ in range(2)])
    res = design(fam, 2, method="lmi")
    assert res.outcome == "stabilized"
    for precision in ("float64", "float32"):
        kit = tmp_path / precision / "kit"
        write(kit, export_kit(res, 2, prefix="plant", family=fam, precision=precision, steps=150, seed=2))
        cmake_build(kit, tmp_path / precision / "build")
        ok = subprocess.run([str(tmp_path / precision / "build" / "plant_replay")], capture_output=True, text=True)
        assert ok.returncode == 0 and "0 entries beyond tolerance" in ok.stdout, ok.stdout
        corrupt(kit / "test" / "plant_replay_data.c")
        subprocess.run(["cmake", "--build", str(tmp_path / precision / "build")], check=True, capture_output=True)
        bad = subprocess.run([str(tmp_path / precision / "build" / "plant_replay")], capture_output=True, text=True)
        assert bad.returncode == 1 and "1 entries beyond tolerance" in bad.stdout, bad.stdout
    app = tmp_path / "app"
    app.mkdir()
    (app / "CMakeLists.txt").write_text(
        "cmake_minimum_required(VERSION 3.13)\nproject(app C)\n"
        f"add_subdirectory({tmp_path / 'float64' / 'kit'} controller)\n"
        "add_executable(app main.c)\ntarget_link_libraries(app PRIVATE plant_controller)\n")
    (app / "main.c").write_text(
        '#include "plant_controller.h"\nint main(void)\n{\n    plant_buffer_t b;\n    double u[PLANT_M];\n'
        "    plant_buffer_init(&b);\n    plant_buffer_output(&b, u);\n    return (u[0] == 0.0) ? 0 : 1;\n}\n")
    cmake_build(app, tmp_path / "app-build")
    assert subprocess.run([str(tmp_path / "app-build" / "app")]).returncode == 0
    assert not (tmp_path / "app-build" / "controller" / "plant_replay").exists()  # the kit's test stays out
