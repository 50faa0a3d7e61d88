"""``python -m bench.codegen_sizes``: flash, RAM and operations of the generated controller on Cortex-M.

For each (n, m, N) and precision, ``solver.export_c`` of random gains is compiled with arm-none-eabi-gcc
``-mthumb -Os -ffunction-sections`` for Cortex-M4 (hard float, single-precision FPU) and Cortex-M0+ (no FPU);
``arm-none-eabi-size`` gives the object's flash (text: code and the gain table; data and bss are 0), and
``-fstack-usage`` the deepest stack frame of the API's functions.  RAM is the caller's ``ncs_buffer_t`` plus that
stack.  Soft-float helpers (libgcc ``__aeabi_*``: double on both cores, float on M0+) are not counted.
Prints the Markdown table of docs/performance.md.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from solver import export_c

CASES = [(2, 1, 3), (4, 2, 5), (10, 3, 10), (20, 4, 10)]
FLAGS = {"M4": ["-mcpu=cortex-m4", "-mthumb", "-mfloat-abi=hard", "-mfpu=fpv4-sp-d16"],
         "M0+": ["-mcpu=cortex-m0plus", "-mthumb", "-mfloat-abi=soft"]}


def measure(n, m, N, precision, core, tmp):
    files = export_c(np.random.default_rng(0).standard_normal((N, m, n)), N)
    if precision == "float32":  # sizes only: the float32 text without a plant to certify against
        files = {k: v.replace("double", "float") for k, v in files.items()}
    for name, text in files.items():
        (tmp / name).write_text(text)
    obj = tmp / "c.o"
    subprocess.run(["arm-none-eabi-gcc", *FLAGS[core], "-std=c99", "-Os", "-ffunction-sections", "-fstack-usage",
                    "-c", "-o", str(obj), str(tmp / "ncs_controller.c")], check=True, cwd=tmp)
    text = int(subprocess.run(["arm-none-eabi-size", str(obj)], capture_output=True, text=True,
                              check=True).stdout.splitlines()[1].split()[0])
    stack = max(int(line.split("\t")[1]) for line in (tmp / "c.su").read_text().splitlines())
    real = 4 if precision == "float32" else 8
    buf = -(-(N * m * real + 16) // real) * real
    return text, buf, stack


def main() -> int:
    if shutil.which("arm-none-eabi-gcc") is None:
        print("arm-none-eabi-gcc is not installed", file=sys.stderr)
        return 1
    print("| n, m, N | multiply-adds per packet | precision | flash M4 (B) | flash M0+ (B) | "
          "RAM: buffer + stack M4 / M0+ (B) |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for n, m, N in CASES:
            for precision in ("float32", "float64"):
                r4 = measure(n, m, N, precision, "M4", tmp)
                r0 = measure(n, m, N, precision, "M0+", tmp)
                print(f"| {n}, {m}, {N} | {N * m * n} | {precision} | {r4[0]} | {r0[0]} | "
                      f"{r4[1]} + {r4[2]} / {r0[1]} + {r0[2]} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
