"""Build and test kit around :func:`solver.export_c`: CMake, an arm-none-eabi toolchain file, and a replay test.

:func:`export_kit` returns the controller's two files plus

* ``CMakeLists.txt``: the static library ``<prefix>_controller`` (``add_subdirectory`` it from a firmware
  project and link the target); built alone (top level) it also builds the replay test and registers it with
  CTest: on the host ``<prefix>_replay``, cross-compiled ``<prefix>_replay_target.elf`` for an MPS2 board run
  under ``qemu-system-arm`` with semihosting;
* ``cmake/arm-none-eabi.cmake``: the toolchain file (``-DNCS_CPU=cortex-m4`` (default, hard float) or
  ``cortex-m0plus``, ``cortex-m3``, ...);
* ``test/``: the replay program, its data (a seeded :func:`solver.simulate` run: the delivered packets and the
  reference inputs with a tolerance per entry), a host ``main`` and, for the target, a startup file, a linker
  script and a semihosting ``main``.

The replay feeds the simulated states of the delivered samples to ``<prefix>_packet``, passes the packets to
the buffer with their stamps, and compares every ``<prefix>_buffer_output`` with the run's input; it exits
non-zero when an entry is off by more than its tolerance: ``2 gamma64(n + 1) |K| |x|`` in float64, the float32
bound of :mod:`solver.precision` (relative and underflow terms) in float32, where the reference is the run of
the rounded gains.
"""

from __future__ import annotations

import numpy as np

from .codegen import export_c
from .errors import InvalidInput
from .precision import gamma32, round_gains


def _gamma64(k: int) -> float:
    u = 2.0**-53
    return k * u / (1.0 - k * u)


def replay_reference(family, gains, n_drop: int, precision: str = "float64", *, steps: int = 200, seed: int = 1,
                     x0=None, loss_model: str = "bernoulli", sensor_loss: float = 0.3, control_loss: float = 0.3):
    """The replay's data: a seeded :func:`solver.simulate` run of the gains the code stores.

    Returns
    -------
    dict
        ``delivered`` (steps,) bool, ``state`` (steps, n) ``x(k)``, ``input`` (steps, m) the reference inputs,
        ``tolerance`` (steps, m), ``gains`` (the simulated gains: rounded for float32), ``run`` (the result).
    """
    from .simulate import simulate

    K = np.asarray(gains, dtype=np.float64)
    if precision == "float32":
        K = round_gains(K)
    n = K.shape[-1]
    x0 = np.ones(n) if x0 is None else x0
    run = simulate(family, K, n_drop, x0=x0, steps=steps, seed=seed, loss_model=loss_model,
                   sensor_loss=sensor_loss, control_loss=control_loss)
    state = run.state[:-1]
    absK = np.abs(K)[run.buffer_index - 1]  # (steps, m, n): the entry played at each sample
    # the state the played packet was computed from: the last delivered sample
    sent = state[np.maximum.accumulate(np.where(run.effective, np.arange(steps), 0))]
    mag = np.einsum("kjn,kn->kj", absK, np.abs(sent))
    if precision == "float32":
        tol = (gamma32(n + 1) + 2 * _gamma64(n + 1)) * mag + 2.0**-126 * (n + absK.sum(axis=-1))
    else:
        tol = 2 * _gamma64(n + 1) * mag + 2.0**-1022 * (n + 1)
    return {"delivered": run.effective.copy(), "state": state, "input": run.input, "tolerance": tol,
            "gains": K, "run": run}


def result_view(result: dict):
    """A design result's JSON (``DesignResult.to_dict()``) as the attributes :func:`export_c` reads from a
    :class:`solver.DesignResult`: gains, outcome, method, certificate (kind, verified, X, P), scaling, decay rate
    and plant switching, so the float32 re-check starts from the design's own certificate when it is stored.

    Raises
    ------
    InvalidInput
        When the result has no gains.
    """
    from types import SimpleNamespace

    if not isinstance(result, dict) or result.get("gains") is None:
        raise InvalidInput("the design result has no gains", ("gains",))
    cert = result.get("certificate") or None
    if isinstance(cert, dict):
        cert = SimpleNamespace(kind=cert.get("kind"), verified=bool(cert.get("verified")),
                               X=None if cert.get("X") is None else np.asarray(cert["X"], dtype=float),
                               P=None if cert.get("P") is None else np.asarray(cert["P"], dtype=float))
    else:
        cert = None
    return SimpleNamespace(gains=np.asarray(result["gains"], dtype=float), outcome=result.get("outcome"),
                           method=result.get("method"), certificate=cert, scaling=result.get("scaling"),
                           decay_rate=result.get("decay_rate"),
                           plant_switching=result.get("plant_switching") or "per_interval")


def _array(values) -> str:
    flat = np.asarray(values, dtype=np.float64).reshape(len(values), -1)
    return ",\n".join("    {" + ", ".join(repr(float(v)) for v in row) + "}" for row in flat)


def export_kit(gains, n_drop: int, exhausted: str = "hold", prefix: str = "ncs", *, metadata: dict | None = None,
               precision: str = "float64", family=None, steps: int = 200, seed: int = 1,
               network=None) -> dict[str, str]:
    """:func:`solver.export_c`'s files plus the build and test kit (module docstring).

    Parameters
    ----------
    gains, n_drop, exhausted, prefix, metadata, precision, family, network
        As for :func:`solver.export_c`.  Without ``family`` the kit has no replay test (nothing to simulate).
    steps : int
        Samples of the replayed run (1..2000).
    seed : int
        Seed of the run (:func:`solver.simulate`, Bernoulli losses 0.3/0.3).

    Returns
    -------
    dict of str to str
        Relative path (``/``-separated) to file text.
    """
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or not 1 <= steps <= 2000:
        raise InvalidInput("steps must be an integer in 1..2000", ("steps",))
    files = export_c(gains, n_drop, exhausted, prefix, metadata=metadata, precision=precision, family=family,
                     network=network)
    p, P = prefix.lower(), prefix.upper()
    real = "double" if precision == "float64" else "float"
    files["CMakeLists.txt"] = _CMAKE.replace("@p@", p).replace("@P@", P)
    files["cmake/arm-none-eabi.cmake"] = _TOOLCHAIN
    if family is None:
        return files
    K = gains.gains if hasattr(gains, "gains") and hasattr(gains, "outcome") else gains
    K = np.asarray(K, dtype=np.float64)
    if K.ndim == 2:
        K = K[:, None, :]
    ref = replay_reference(family, K, n_drop, precision, steps=int(steps), seed=int(seed))
    n, m = K.shape[-1], K.shape[-2]
    data = _DATA.format(p=p, P=P, steps=steps, n=n, m=m, precision=precision, seed=seed,
                        delivered=", ".join(str(int(v)) + "u" for v in ref["delivered"]),
                        state=_array(ref["state"]), input=_array(ref["input"]), tol=_array(ref["tolerance"]))
    sub = {"@p@": p, "@P@": P, "@real@": real}
    for name, text in _TEST_FILES.items():
        for k, v in sub.items():
            text = text.replace(k, v)
            name = name.replace(k, v)
        files[f"test/{name}"] = text
    files[f"test/{p}_replay_data.c"] = data
    return files


_CMAKE = """\
# Build of the generated controller (ncs-design, solver.export_kit).
#   In a firmware project:   add_subdirectory(path/to/this) and target_link_libraries(app PRIVATE @p@_controller)
#   Host replay test:        cmake -S . -B build && cmake --build build && ctest --test-dir build
#   Emulated Cortex-M:       cmake -S . -B build-arm -DCMAKE_TOOLCHAIN_FILE=cmake/arm-none-eabi.cmake
#                            [-DNCS_CPU=cortex-m0plus]
#                            cmake --build build-arm && ctest --test-dir build-arm   (needs qemu-system-arm)
cmake_minimum_required(VERSION 3.13)
project(@p@_controller C)

add_library(@p@_controller STATIC @p@_controller.c)
target_include_directories(@p@_controller PUBLIC ${CMAKE_CURRENT_SOURCE_DIR})
set_target_properties(@p@_controller PROPERTIES C_STANDARD 99 C_STANDARD_REQUIRED ON C_EXTENSIONS OFF)
if(CMAKE_C_COMPILER_ID STREQUAL "GNU" OR CMAKE_C_COMPILER_ID MATCHES "Clang")
    target_compile_options(@p@_controller PRIVATE -Wall -Wextra -pedantic)
    if(CMAKE_SOURCE_DIR STREQUAL CMAKE_CURRENT_SOURCE_DIR)
        target_compile_options(@p@_controller PRIVATE -Werror)  # not imposed on a parent project's compiler
    endif()
endif()

# The replay test, when this directory is the top-level project and the kit has its data.
if(CMAKE_SOURCE_DIR STREQUAL CMAKE_CURRENT_SOURCE_DIR AND EXISTS ${CMAKE_CURRENT_SOURCE_DIR}/test/@p@_replay_data.c)
    enable_testing()
    set(REPLAY test/@p@_replay.c test/@p@_replay_data.c)
    if(CMAKE_CROSSCOMPILING)
        add_executable(@p@_replay_target.elf ${REPLAY} test/@p@_replay_target.c test/startup_mps2.c)
        target_link_libraries(@p@_replay_target.elf PRIVATE @p@_controller)
        target_link_options(@p@_replay_target.elf PRIVATE -nostdlib -nostartfiles
                            -T${CMAKE_CURRENT_SOURCE_DIR}/test/mps2.ld -Wl,--gc-sections)
        target_link_libraries(@p@_replay_target.elf PRIVATE gcc)
        find_program(QEMU_SYSTEM_ARM qemu-system-arm)
        if(QEMU_SYSTEM_ARM)
            if(NCS_CPU STREQUAL "cortex-m4")
                set(BOARD mps2-an386)
            else()
                set(BOARD mps2-an385)  # Cortex-M3: runs ARMv6-M (M0/M0+) code too
            endif()
            add_test(NAME @p@_replay_target
                     COMMAND ${QEMU_SYSTEM_ARM} -M ${BOARD} -nographic -monitor none -serial none
                             -semihosting-config enable=on,target=native
                             -kernel $<TARGET_FILE:@p@_replay_target.elf>)
        endif()
    else()
        add_executable(@p@_replay ${REPLAY} test/@p@_replay_main.c)
        target_link_libraries(@p@_replay PRIVATE @p@_controller)
        add_test(NAME @p@_replay COMMAND @p@_replay)
    endif()
endif()
"""

_TOOLCHAIN = """\
# arm-none-eabi toolchain (Debian/Ubuntu gcc-arm-none-eabi). -DNCS_CPU=cortex-m4 (default: hard float,
# single-precision FPU) or cortex-m0plus, cortex-m3, cortex-m7, ...
set(CMAKE_SYSTEM_NAME Generic)
set(CMAKE_SYSTEM_PROCESSOR arm)
set(CMAKE_C_COMPILER arm-none-eabi-gcc)
set(CMAKE_TRY_COMPILE_TARGET_TYPE STATIC_LIBRARY)
if(NOT NCS_CPU)
    set(NCS_CPU cortex-m4)
endif()
set(NCS_CPU ${NCS_CPU} CACHE STRING "Cortex-M core (-mcpu)")
list(APPEND CMAKE_TRY_COMPILE_PLATFORM_VARIABLES NCS_CPU)
if(NCS_CPU STREQUAL "cortex-m4")
    set(NCS_FPU "-mfloat-abi=hard -mfpu=fpv4-sp-d16")
else()
    set(NCS_FPU "-mfloat-abi=soft")
endif()
set(CMAKE_C_FLAGS_INIT "-mcpu=${NCS_CPU} -mthumb ${NCS_FPU} -Os -ffunction-sections -fdata-sections")
set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)
set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE ONLY)
"""

_DATA = """\
/* {p}_replay_data.c: a seeded solver.simulate run (seed {seed}, Bernoulli losses 0.3/0.3, {steps} samples) of the
 * gains {p}_controller.c stores ({precision}): the states of the delivered samples, the reference inputs and
 * the tolerance of every entry. Generated by ncs-design (solver.export_kit). */
#include "{p}_replay.h"

const uint32_t {p}_replay_steps = {steps}u;
const uint8_t {p}_replay_delivered[{steps}] = {{{delivered}}};
const double {p}_replay_state[{steps}][{n}] = {{
{state}
}};
const double {p}_replay_input[{steps}][{m}] = {{
{input}
}};
const double {p}_replay_tolerance[{steps}][{m}] = {{
{tol}
}};
"""

_TEST_FILES = {
    "@p@_replay.h": """\
/* @p@_replay.h: replay of a simulated packet sequence against its reference inputs (solver.export_kit). */
#ifndef @P@_REPLAY_H
#define @P@_REPLAY_H

#include <stdint.h>
#include "@p@_controller.h"

extern const uint32_t @p@_replay_steps;
extern const uint8_t @p@_replay_delivered[];
extern const double @p@_replay_state[][@P@_N];
extern const double @p@_replay_input[][@P@_M];
extern const double @p@_replay_tolerance[][@P@_M];

/* Called with every output u(k) (platform hook: print it, or nothing). */
void @p@_replay_emit(uint32_t k, const @real@ u[]);
/* Replays every sample; returns the number of entries off by more than their tolerance and the worst
 * error / tolerance ratio in *worst. */
uint32_t @p@_replay_run(double *worst);

#endif
""",
    "@p@_replay.c": """\
/* @p@_replay.c: see @p@_replay.h. */
#include "@p@_replay.h"

uint32_t @p@_replay_run(double *worst)
{
    @p@_buffer_t b;
    @real@ x[@P@_N];
    @real@ packet[@P@_PACKET_LEN];
    @real@ u[@P@_M];
    uint32_t k;
    uint32_t i;
    uint32_t bad = 0u;
    *worst = 0.0;
    @p@_buffer_init(&b);
    for (k = 0u; k < @p@_replay_steps; ++k) {
        if (@p@_replay_delivered[k] != 0u) {
            for (i = 0u; i < @P@_N; ++i) {
                x[i] = (@real@)@p@_replay_state[k][i];
            }
            @p@_packet(x, packet);
            @p@_buffer_receive(&b, packet, k);
        }
        @p@_buffer_output(&b, u);
        @p@_replay_emit(k, u);
        for (i = 0u; i < @P@_M; ++i) {
            double err = (double)u[i] - @p@_replay_input[k][i];
            double tol = @p@_replay_tolerance[k][i];
            err = (err < 0.0) ? -err : err;
            if (!(err <= tol)) {
                ++bad;
            }
            if ((tol > 0.0) && (err / tol > *worst)) {
                *worst = err / tol;
            }
        }
    }
    return bad;
}
""",
    "@p@_replay_main.c": """\
/* @p@_replay_main.c: host replay test; exit status 1 on a mismatch beyond the tolerance. */
#include <stdio.h>
#include "@p@_replay.h"

void @p@_replay_emit(uint32_t k, const @real@ u[])
{
    (void)k;
    (void)u;
}

int main(void)
{
    double worst;
    uint32_t bad = @p@_replay_run(&worst);
    printf("@p@ replay: %u samples, %u entries beyond tolerance, worst error/tolerance %.3g\\n",
           (unsigned)@p@_replay_steps, (unsigned)bad, worst);
    return bad == 0u ? 0 : 1;
}
""",
    "@p@_replay_target.c": """\
/* @p@_replay_target.c: the replay on an MPS2 board (QEMU) with ARM semihosting: prints every output as hex
 * ("u <k> <j> <bits>"), a summary, and exits with status 1 on a mismatch beyond the tolerance. */
#include <stdint.h>
#include <string.h>
#include "@p@_replay.h"

static void sh_call(uint32_t op, const void *arg)
{
    register uint32_t r0 __asm__("r0") = op;
    register const void *r1 __asm__("r1") = arg;
    __asm__ volatile("bkpt 0xAB" : "+r"(r0) : "r"(r1) : "memory");
}

static char *put_hex(char *s, uint64_t v, uint32_t digits)
{
    uint32_t i;
    for (i = 0u; i < digits; ++i) {
        uint32_t d = (uint32_t)(v >> (4u * (digits - 1u - i))) & 0xFu;
        s[i] = (char)(d < 10u ? ('0' + d) : ('a' + d - 10u));
    }
    return s + digits;
}

void @p@_replay_emit(uint32_t k, const @real@ u[])
{
    char line[64];
    uint32_t j;
    for (j = 0u; j < @P@_M; ++j) {
        char *s = line;
        uint64_t bits = 0u;
        memcpy(&bits, &u[j], sizeof(u[j]));
        *s++ = 'u'; *s++ = ' ';
        s = put_hex(s, k, 8u); *s++ = ' ';
        s = put_hex(s, j, 8u); *s++ = ' ';
        s = put_hex(s, bits, 2u * (uint32_t)sizeof(u[j]));
        *s++ = '\\n'; *s = '\\0';
        sh_call(0x04u, line); /* SYS_WRITE0 */
    }
}

int main(void)
{
    char line[64];
    double worst;
    uint32_t bad = @p@_replay_run(&worst);
    char *s = line;
    memcpy(s, "bad ", 4u);
    s = put_hex(s + 4, bad, 8u);
    *s++ = '\\n'; *s = '\\0';
    sh_call(0x04u, line);
    /* SYS_EXIT: ADP_Stopped_ApplicationExit (status 0) or ADP_Stopped_RunTimeErrorUnknown (status 1) */
    sh_call(0x18u, (const void *)(uintptr_t)(bad == 0u ? 0x20026u : 0x20023u));
    return 0;
}
""",
    "startup_mps2.c": """\
/* startup_mps2.c: minimal Cortex-M start-up for the QEMU MPS2 boards (vector table, .data/.bss, FPU on). */
#include <stddef.h>
#include <stdint.h>

extern uint32_t _sidata, _sdata, _edata, _sbss, _ebss, _estack;
int main(void);
void Reset_Handler(void);
void Default_Handler(void);

void *memcpy(void *dst, const void *src, size_t n)
{
    unsigned char *d = dst;
    const unsigned char *s = src;
    while (n-- > 0u) { *d++ = *s++; }
    return dst;
}

void *memset(void *dst, int c, size_t n)
{
    unsigned char *d = dst;
    while (n-- > 0u) { *d++ = (unsigned char)c; }
    return dst;
}

void Default_Handler(void)
{
    for (;;) { }
}

void Reset_Handler(void)
{
    uint32_t *src = &_sidata;
    uint32_t *dst;
    for (dst = &_sdata; dst < &_edata;) { *dst++ = *src++; }
    for (dst = &_sbss; dst < &_ebss;) { *dst++ = 0u; }
#if defined(__ARM_FP)
    *(volatile uint32_t *)0xE000ED88u |= (0xFu << 20); /* CPACR: CP10 and CP11 full access */
    __asm__ volatile("dsb\\n isb");
#endif
    (void)main();
    Default_Handler();
}

__attribute__((section(".isr_vector"), used))
const void *const vector_table[16] = {
    &_estack, (void *)Reset_Handler, (void *)Default_Handler, (void *)Default_Handler,
    (void *)Default_Handler, (void *)Default_Handler, (void *)Default_Handler, 0, 0, 0, 0,
    (void *)Default_Handler, (void *)Default_Handler, 0, (void *)Default_Handler, (void *)Default_Handler,
};
""",
    "mps2.ld": """\
/* mps2.ld: QEMU MPS2 (AN385/AN386): 4 MB code memory at 0, 4 MB SRAM at 0x20000000. */
ENTRY(Reset_Handler)
MEMORY
{
    FLASH (rx) : ORIGIN = 0x00000000, LENGTH = 4M
    RAM (rwx)  : ORIGIN = 0x20000000, LENGTH = 4M
}
_estack = ORIGIN(RAM) + LENGTH(RAM);
SECTIONS
{
    .text : { KEEP(*(.isr_vector)) *(.text*) *(.rodata*) . = ALIGN(4); } > FLASH
    .ARM.exidx : { *(.ARM.exidx*) } > FLASH
    _sidata = LOADADDR(.data);
    .data : { . = ALIGN(4); _sdata = .; *(.data*) . = ALIGN(4); _edata = .; } > RAM AT > FLASH
    .bss : { . = ALIGN(4); _sbss = .; *(.bss*) *(COMMON) . = ALIGN(4); _ebss = .; } > RAM
}
""",
}
