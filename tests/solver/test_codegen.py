"""The generated C controller and buffer, compiled with gcc and driven through ctypes.

References: :func:`solver.simulate` (the bound respected), and below an independent
Python model of the buffer (every received packet kept, the newest stamp chosen at
each output, Python's unbounded integers for stamps) for bursts past the bound, late,
reordered and duplicated packets and stamps that wrap around 2^32.
"""

from __future__ import annotations

import ctypes
import itertools
import subprocess

import numpy as np
import pytest

from solver import InvalidInput, PlantFamily, design, export_c, simulate

from .paper_data import EQ23_GAINS

STRICT = ["gcc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic"]
PAPER = PlantFamily.paper_example(0.1)
_LIBS = itertools.count()


def build(tmp_path, *controllers):
    """Write every ``export_c`` output to tmp_path and link them into one shared library."""
    sources = []
    for files in controllers:
        for name, text in files.items():
            (tmp_path / name).write_text(text)
            if name.endswith(".c"):
                sources.append(str(tmp_path / name))
    lib = tmp_path / f"libctrl{next(_LIBS)}.so"  # a fresh path: dlopen would return a loaded library again
    subprocess.run(STRICT + ["-O2", "-shared", "-fPIC", "-o", str(lib)] + sources, check=True,
                   capture_output=True, text=True)
    return ctypes.CDLL(str(lib))


class CBuffer:
    """The generated C API, one function per call."""

    def __init__(self, lib, prefix, m, n_drop, dtype=np.float64):
        self.m, self.n_drop, self.dtype = m, n_drop, dtype
        self.fn = {name: getattr(lib, f"{prefix}_{name}") for name in
                   ("buffer_size", "packet", "buffer_init", "buffer_set_clock", "buffer_receive", "buffer_output")}
        self.fn["buffer_size"].restype = ctypes.c_size_t
        self.fn["buffer_receive"].argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint32]
        self.fn["buffer_set_clock"].argtypes = [ctypes.c_void_p, ctypes.c_uint32]
        self.mem = ctypes.create_string_buffer(self.fn["buffer_size"]())
        self.fn["buffer_init"](self.mem)

    def set_clock(self, now):
        self.fn["buffer_set_clock"](self.mem, now % 2**32)

    def packet(self, x):
        x = np.ascontiguousarray(x, dtype=self.dtype)
        out = np.empty(self.n_drop * self.m, dtype=self.dtype)
        self.fn["packet"](x.ctypes.data_as(ctypes.c_void_p), out.ctypes.data_as(ctypes.c_void_p))
        return out

    def receive(self, packet, stamp):
        packet = np.ascontiguousarray(packet, dtype=self.dtype)
        self.fn["buffer_receive"](self.mem, packet.ctypes.data_as(ctypes.c_void_p), stamp % 2**32)

    def output(self):
        u = np.empty(self.m, dtype=self.dtype)
        self.fn["buffer_output"](self.mem, u.ctypes.data_as(ctypes.c_void_p))
        return u


class ModelBuffer:
    """Independent reference: keeps every packet, picks the newest stamp at each output."""

    def __init__(self, K, exhausted, now=0):
        self.K, self.exhausted, self.now, self.got, self.ages = K, exhausted, now, [], []

    def receive(self, x, stamp):
        if stamp <= self.now:  # a stamp ahead of the clock is refused
            self.got.append((stamp, np.array(x)))

    def set_clock(self, now):
        """The newest stamp is re-aged against the new clock; ahead of it, the buffer forgets everything."""
        self.now = now
        if self.got and max(s for s, _ in self.got) > now:
            self.got = []

    def output(self):
        N, m, _ = self.K.shape
        if not self.got:
            u = np.zeros(m)
        else:
            stamp, x = max(self.got, key=lambda p: p[0])  # ties: the first received (max keeps it)
            d = self.now - stamp
            self.ages.append(d)
            u = self.K[d] @ x if d < N else (self.K[N - 1] @ x if self.exhausted == "hold" else np.zeros(m))
        self.now += 1
        return u


def assert_inputs_agree(a, b):
    scale = max(1.0, float(np.max(np.abs(b))))
    np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * scale)


@pytest.fixture(scope="module")
def paper_design():
    res = design(PAPER, 3, method="lmi")
    assert res.outcome == "stabilized"
    return res


def test_strict_c99_compiles_and_header_names_the_design(tmp_path, paper_design):
    files = export_c(paper_design, n_drop=3, metadata={"id": "d-42"})
    assert set(files) == {"ncs_controller.h", "ncs_controller.c"}
    head = files["ncs_controller.h"]
    for text in ("#define NCS_N 2", "#define NCS_M 1", "#define NCS_N_DROP 3", "id: d-42", "method: lmi",
                 f"certificate: {paper_design.certificate.kind}", "size_t ncs_buffer_size(void);",
                 "void ncs_buffer_receive(ncs_buffer_t *b, const double packet[], uint32_t stamp);",
                 "ncs_packet 6 multiply-adds (N m n)",
                 "ncs_buffer_receive and ncs_buffer_output 0 multiply-adds (copies: 3 and 1 values)"):
        assert text in head
    src = files["ncs_controller.c"]
    assert "malloc" not in src and "static const double ncs_gains" in src
    # the only file-scope object is the gain table (no mutable global state)
    (tmp_path / "ncs_controller.h").write_text(head)
    (tmp_path / "ncs_controller.c").write_text(src)
    obj = tmp_path / "c.o"
    subprocess.run(STRICT + ["-c", "-o", str(obj), str(tmp_path / "ncs_controller.c")], check=True)
    syms = subprocess.run(["nm", str(obj)], capture_output=True, text=True, check=True).stdout.split("\n")
    data = [s for s in syms if s[17:19].strip() in ("D", "d", "B", "b", "C")]
    assert data == [], data


def test_packet_is_the_gains_times_the_state(tmp_path):
    rng = np.random.default_rng(0)
    K = rng.standard_normal((4, 3, 5))
    c = CBuffer(build(tmp_path, export_c(K, 4)), "ncs", 3, 4)
    for _ in range(5):
        x = rng.standard_normal(5)
        assert_inputs_agree(c.packet(x).reshape(4, 3), K @ x)


@pytest.mark.parametrize("loss_model", ["paper", "bernoulli"])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_closed_loop_matches_simulate(tmp_path, paper_design, loss_model, seed):
    """Packets delivered at simulate's effective steps: the C buffer closes the same loop."""
    c = CBuffer(build(tmp_path, export_c(paper_design, 3)), "ncs", 1, 3)
    sim = simulate(PAPER, paper_design.gains, 3, x0=[-3, 2], steps=150, seed=seed, loss_model=loss_model,
                   sensor_loss=0.3, control_loss=0.3)
    x = sim.state[0]
    for k in range(150):
        if sim.effective[k]:
            c.receive(c.packet(x), k)
        u = c.output()
        assert_inputs_agree(u, sim.input[k])
        x = PAPER.F[sim.mode[k]] @ x + PAPER.G[sim.mode[k]] @ u
        np.testing.assert_allclose(x, sim.state[k + 1], rtol=1e-10, atol=1e-12)
    assert not np.all(sim.effective)  # losses did happen


def run_channel(c, model, family, x0, steps, rng, start=0, loss=0.3, max_delay=3, burst=(0.05, 8),
                duplicate=0.1):
    """A closed loop over a random channel: losses, bursts past the bound, delays (so reordering), duplicates.

    The state follows the model's inputs; the C buffer gets the very same packets.  Returns the
    (model, C) inputs and how many packets arrived late and out of order.
    """
    x = np.array(x0, dtype=float)
    in_flight: dict[int, list] = {}
    burst_left = 0
    late = reordered = 0
    newest_delivered = None
    u_model, u_c = [], []
    for k in range(start, start + steps):
        mode = int(rng.integers(family.n_modes))
        if burst_left == 0 and rng.random() < burst[0]:
            burst_left = int(rng.integers(family.n_modes + 3, burst[1] + 1))
        if burst_left:
            burst_left -= 1
        elif rng.random() >= loss:
            copies = 2 if rng.random() < duplicate else 1
            for _ in range(copies):
                delay = int(rng.integers(0, max_delay + 1)) if rng.random() < 0.5 else 0
                in_flight.setdefault(k + delay, []).append((k, x.copy(), c.packet(x)))
        arriving = in_flight.pop(k, [])
        rng.shuffle(arriving)
        for stamp, xs, packet in arriving:
            late += stamp < k
            if newest_delivered is not None and stamp < newest_delivered:
                reordered += 1
            newest_delivered = stamp if newest_delivered is None else max(stamp, newest_delivered)
            model.receive(xs, stamp)
            c.receive(packet, stamp)
        um, uc = model.output(), c.output()
        u_model.append(um)
        u_c.append(uc)
        x = family.F[mode] @ x + family.G[mode] @ um
    return np.array(u_model), np.array(u_c), late, reordered


@pytest.mark.parametrize("exhausted", ["hold", "zero"])
@pytest.mark.parametrize("seed", [10, 11, 12])
def test_bursts_late_reordered_duplicates_match_the_model(tmp_path, paper_design, exhausted, seed):
    K = paper_design.gains
    c = CBuffer(build(tmp_path, export_c(K, 3, exhausted=exhausted)), "ncs", 1, 3)
    model = ModelBuffer(K, exhausted)
    rng = np.random.default_rng(seed)
    u_model, u_c, late, reordered = run_channel(c, model, PAPER, [-3, 2], 400, rng)
    assert late > 0 and reordered > 0
    assert_inputs_agree(u_c, u_model)
    assert max(model.ages) >= 3  # bursts past the bound: the exhausted policy was applied


@pytest.mark.parametrize("seed", [20, 21])
def test_stamps_wrap_around_2_to_the_32(tmp_path, seed):
    rng = np.random.default_rng(seed)
    n, m, N = 3, 2, 4
    F = [0.9 * np.linalg.qr(rng.standard_normal((n, n)))[0] for _ in range(2)]
    fam = PlantFamily(F=F, G=[rng.standard_normal((n, m)) for _ in range(2)])
    K = 0.2 * rng.standard_normal((N, m, n))
    c = CBuffer(build(tmp_path, export_c(K, N, prefix="wrap")), "wrap", m, N)
    start = 2**32 - 150
    c.set_clock(start)
    model = ModelBuffer(K, "hold", now=start)
    u_model, u_c, late, reordered = run_channel(c, model, fam, rng.standard_normal(n), 300, rng, start=start)
    assert late > 0 and reordered > 0 and max(model.ages) >= N
    assert_inputs_agree(u_c, u_model)


def test_buffer_rules_step_by_step(tmp_path):
    K = np.arange(1.0, 4.0).reshape(3, 1, 1)  # K_q = q, x = 1 packets: u = index of the entry + 1
    for exhausted, tail in (("hold", 3.0), ("zero", 0.0)):
        c = CBuffer(build(tmp_path, export_c(K, 3, exhausted=exhausted)), "ncs", 1, 3)
        seq = [c.output()[0]]  # now 0: nothing yet
        c.receive(c.packet([10.0]), 2)  # now 1: a stamp from the future is refused
        seq.append(c.output()[0])
        c.receive(c.packet([1.0]), 1)  # now 2: late by one sample, entry K_2
        seq.append(c.output()[0])
        c.receive(c.packet([100.0]), 0)  # now 3: older than the held one, ignored
        c.receive(c.packet([200.0]), 1)  # duplicate stamp, ignored
        seq += [c.output()[0] for _ in range(3)]  # K_3, then exhausted twice
        c.receive(c.packet([5.0]), 4)  # now 6: stamp 4, d = 2
        seq.append(c.output()[0])
        assert seq == [0.0, 0.0, 2.0, 3.0, tail, tail, 15.0]


def test_two_prefixes_link_into_one_program(tmp_path):
    a = export_c(EQ23_GAINS, 3, prefix="left")
    b = export_c(np.zeros((2, 2, 3)), 2, exhausted="zero", prefix="Right")
    assert set(b) == {"right_controller.h", "right_controller.c"} and "#define RIGHT_N_DROP 2" in b["right_controller.h"]
    lib = build(tmp_path, a, b)
    assert CBuffer(lib, "left", 1, 3).packet([1.0, 0.0]).shape == (3,)
    assert CBuffer(lib, "right", 2, 2).packet([1.0, 2.0, 3.0]).tolist() == [0.0] * 4


@pytest.mark.parametrize("kwargs, field", [
    ({"prefix": "1abc"}, "prefix"), ({"prefix": "a b"}, "prefix"), ({"prefix": 3}, "prefix"),
    ({"exhausted": "last"}, "exhausted"), ({"n_drop": 0}, "n_drop"), ({"n_drop": 2}, "gains"),
    ({"gains": [[1.0, float("nan")]] * 3}, "gains"), ({"gains": "K"}, "gains"),
])
def test_bad_input_names_the_field(kwargs, field):
    args = {"gains": EQ23_GAINS, "n_drop": 3, **kwargs}
    with pytest.raises(InvalidInput) as err:
        export_c(args.pop("gains"), args.pop("n_drop"), **args)
    assert err.value.field == (field,)


HOSTILE = ["x */ int evil; /*", "??/", "a ??/\n#define NCS_N 99", "%s%n%x", "\\", "tail \\", "// line",
           "*/", "/*", "\r\n#include <stdio.h>\n", "\x00\x07\x1b[31m", "é ☃ \u202e", "{p} {P} {{", "`$(rm -rf /)`",
           "a" * 5000]


@pytest.mark.parametrize("hostile", HOSTILE)
def test_hostile_metadata_never_breaks_the_strict_build_or_injects(tmp_path, hostile):
    files = export_c(EQ23_GAINS, 3, metadata={hostile: hostile, "id": hostile})
    head = files["ncs_controller.h"]
    comment, rest = head.split("*/", 1)  # the header comment ends at its first terminator...
    assert "#ifndef NCS_CONTROLLER_H" in rest and "method" not in rest  # ...after every metadata line
    for bad in ("/*", "//", "??", "\\", "%"):
        assert bad not in comment[2:], bad
    assert all(32 <= ord(ch) < 127 for line in comment.split("\n") for ch in line)
    assert max(len(line) for line in comment.split("\n")) < 200
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    subprocess.run(STRICT + ["-trigraphs", "-Werror=comment", "-Werror=trigraphs", "-c", "-o",
                             str(tmp_path / "c.o"), str(tmp_path / "ncs_controller.c")], check=True)
    macros = subprocess.run(["gcc", "-std=c99", "-E", "-dM", str(tmp_path / "ncs_controller.h")],
                            capture_output=True, text=True, check=True).stdout
    ours = sorted(line.split()[1] for line in macros.splitlines() if line.split()[1].startswith("NCS_"))
    assert ours == ["NCS_CONTROLLER_H", "NCS_EXHAUSTED_HOLD", "NCS_M", "NCS_N", "NCS_N_DROP", "NCS_PACKET_LEN"]
    assert "#define NCS_N 2u" in macros


@pytest.mark.parametrize("metadata", [["id"], {1: "x"}, "id"])
def test_metadata_must_be_a_dict_with_str_keys(metadata):
    with pytest.raises(InvalidInput) as err:
        export_c(EQ23_GAINS, 3, metadata=metadata)
    assert err.value.field == ("metadata",)


def test_set_clock_after_packets_recomputes_the_age_from_the_stamp(tmp_path):
    """The reported case: a packet, then the clock set forward; a newer stamp must replace it."""
    K = np.arange(1.0, 4.0).reshape(3, 1, 1)
    c = CBuffer(build(tmp_path, export_c(K, 3)), "ncs", 1, 3)
    c.set_clock(5)
    c.receive(c.packet([1.0]), 5)
    c.set_clock(100)  # age of stamp 5 is now 95: exhausted, "hold" plays K_3
    assert c.output()[0] == 3.0
    c.receive(c.packet([10.0]), 99)  # newer stamp (age 2 at now 101): kept
    assert c.output()[0] == 30.0
    c.set_clock(99)  # backwards: stamp 99 has age 0 again
    assert c.output()[0] == 10.0
    c.set_clock(50)  # the held stamp is ahead of the new clock: dropped, zeros until a packet
    assert c.output()[0] == 0.0
    c.receive(c.packet([2.0]), 50)  # now 51: age 1, entry K_2
    assert c.output()[0] == 4.0


@pytest.mark.parametrize("seed", [30, 31, 32])
def test_set_clock_between_packets_matches_the_model(tmp_path, seed):
    """Clock jumps (forward and back) between random deliveries: newest stamp wins against the model."""
    rng = np.random.default_rng(seed)
    K = rng.standard_normal((3, 2, 3))
    c = CBuffer(build(tmp_path, export_c(K, 3)), "ncs", 2, 3)
    start = int(rng.integers(0, 2**32 - 2000))
    c.set_clock(start)
    model = ModelBuffer(K, "hold", now=start)
    jumps = 0
    for _ in range(600):
        event = rng.random()
        if event < 0.08:
            now = model.now + int(rng.integers(-6, 12))
            c.set_clock(now)
            model.set_clock(now)
            jumps += 1
        elif event < 0.6:
            stamp = model.now - int(rng.integers(-2, 8))
            x = rng.standard_normal(3)
            c.receive(c.packet(x), stamp)
            model.receive(x, stamp)
        assert_inputs_agree(c.output(), model.output())
    assert jumps > 20


# ------------------------------------------------------------------ float32
def rounding_bound(K32, x):
    """Entrywise bound of the float32 packet (docs/design.md, "Single precision"), plus float64 reference error."""
    n = K32.shape[-1]
    g = (n + 1) * 2.0**-24 / (1 - (n + 1) * 2.0**-24)
    # absolute part: underflow, gradual or flushed to zero (2^-126 per rounding of x_i and per product)
    return (g + 1e-15) * (np.abs(K32) @ np.abs(x)) + 2.0**-126 * (n + np.abs(K32).sum(axis=-1))


def test_float32_paper_example_is_certified_and_the_sil_run_stays_within_the_bound(tmp_path, paper_design):
    files = export_c(paper_design, 3, precision="float32", family=PAPER)
    head, src = files["ncs_controller.h"], files["ncs_controller.c"]
    assert "void ncs_packet(const float x[], float packet[]);" in head
    assert "float32: gains rounded to float32; decay rate" in head and "double" not in src
    K32 = paper_design.gains.astype(np.float32).astype(np.float64)
    c = CBuffer(build(tmp_path, files), "ncs", 1, 3, dtype=np.float32)
    sim = simulate(PAPER, K32, 3, x0=[-3, 2], steps=200, seed=5)
    x = sim.state[0]
    worst = 0.0
    for k in range(200):
        if sim.effective[k]:
            sent = x
            c.receive(c.packet(x), k)
        u = c.output().astype(np.float64)
        ref = K32[sim.buffer_index[k] - 1] @ sent  # the rounded gains in exact-ish float64
        bound = rounding_bound(K32[sim.buffer_index[k] - 1], sent)
        assert np.all(np.abs(u - ref) <= bound), (k, u, ref, bound)
        worst = max(worst, float(np.max(np.abs(u - ref) / np.maximum(bound, 1e-300))))
        x = PAPER.F[sim.mode[k]] @ x + PAPER.G[sim.mode[k]] @ u  # the loop closes on the float32 input
    assert np.linalg.norm(x) < 1e-3 * np.linalg.norm(sim.state[0])  # and it converges
    assert worst > 0  # float32 rounding did happen (the bound is not vacuous)


def test_float32_refuses_a_design_whose_rounding_loses_the_proof():
    """At the maximal decay rate the certificate's room is about RECHECK_TOL: float32 rounding exceeds it."""
    res = design(PAPER, 3, method="lmi", decay_rate="max")
    assert res.outcome == "stabilized"
    export_c(res, 3)  # float64 is exported as before
    with pytest.raises(InvalidInput) as err:
        export_c(res, 3, precision="float32", family=PAPER)
    assert err.value.field == ("precision",)
    assert "lose the proof of decay rate" in str(err.value) and "export in float64" in str(err.value)
    # the same gains without the rate claim: stability survives the rounding
    assert "re-checked" in export_c(res.gains, 3, precision="float32", family=PAPER)["ncs_controller.h"]


def random_family(rng, n, m, r):
    F = [np.linalg.qr(rng.standard_normal((n, n)))[0] * rng.uniform(0.9, 1.15) for _ in range(r)]
    return PlantFamily(F=F, G=[rng.standard_normal((n, m)) for _ in range(r)])


def test_float32_twenty_random_designs_are_certified(tmp_path):
    """Twenty random plants: each stabilized design exports in float32 with the rounding inside the proof, and the
    proof is independent: the float32 loop's own certificate (a fresh LMI on the rounded gains) passes too."""
    from solver.precision import certify_float32

    rng = np.random.default_rng(7)
    done = 0
    while done < 20:
        n, m, r, N = int(rng.integers(2, 5)), int(rng.integers(1, 3)), int(rng.integers(1, 3)), int(rng.integers(1, 4))
        fam = random_family(rng, n, m, r)
        res = design(fam, N, method="lmi")
        if res.outcome != "stabilized":
            continue
        files = export_c(res, N, precision="float32", family=fam, prefix=f"r{done}")
        assert "re-checked on them" in files[f"r{done}_controller.h"]
        proof = certify_float32(fam, res.gains, N)  # no design certificate: a fresh one for the float32 loop
        assert proof.verified and proof.source == "fixed_gain_lmi" and 0 < proof.rounding_share < 1
        done += 1


def test_float32_needs_the_family_and_checks_its_sizes():
    with pytest.raises(InvalidInput) as err:
        export_c(EQ23_GAINS, 3, precision="float32")
    assert err.value.field == ("family",)
    with pytest.raises(InvalidInput) as err:
        export_c(np.ones((3, 1, 3)), 3, precision="float32", family=PAPER)
    assert err.value.field == ("family",)
    with pytest.raises(InvalidInput) as err:
        export_c(EQ23_GAINS, 3, precision="float16", family=PAPER)
    assert err.value.field == ("precision",)


@pytest.mark.parametrize("options", [{"method": "switched"}, {"method": "lmi", "plant_switching": "per_sample"},
                                     {"method": "lmi", "scheme": "hold"}])
def test_float32_keeps_the_designs_claim_and_certificate(options):
    """Switched (mode-dependent P_s) and per-sample certificates are re-checked as they are, at the design's rate."""
    from solver.precision import certify_float32

    res = design(PAPER, 3, **options)
    assert res.outcome == "stabilized" and res.decay_rate is not None
    proof = certify_float32(PAPER, res.gains, 3, plant_switching=res.plant_switching, decay_rate=res.decay_rate,
                            certificate=res.certificate)
    assert proof.verified and proof.source == "design" and proof.claim.startswith("decay rate")
    head = export_c(res, 3, precision="float32", family=PAPER)["ncs_controller.h"]
    assert f"decay rate {res.decay_rate:.6g} re-checked on them (design certificate" in head


def test_beta_bounds_the_float32_rounding_over_an_interval():
    """Independent of the C code: float32 packets computed with numpy's float32 (sequential sums) perturb every
    interval by at most beta_s |x| (the bound the proof covers), and the bound is not loose by orders."""
    from solver.network import ModeSet
    from solver.precision import certify_float32

    rng = np.random.default_rng(9)
    fam = random_family(rng, 4, 2, 2)
    K = 0.3 * rng.standard_normal((3, 2, 4))
    proof = certify_float32(fam, K, 3)
    K32 = proof.gains.astype(np.float32)
    modes = ModeSet.from_family(fam, 3)
    ratio = 0.0
    for _ in range(300):
        x = rng.standard_normal(4) * 10.0 ** rng.uniform(-3, 3)
        x32 = x.astype(np.float32)
        u32 = np.empty((3, 2))
        for q in range(3):
            for j in range(2):
                s = np.float32(0.0)
                for i in range(4):
                    s = np.float32(s + np.float32(K32[q, j, i] * x32[i]))
                u32[q, j] = s
        err = u32 - proof.gains @ x  # (3, 2): the rounding of every entry
        w = np.einsum("sqab,qb->sa", modes.coef, err)
        r = np.linalg.norm(w, axis=1) / (proof.beta * np.linalg.norm(x))
        ratio = max(ratio, float(r.max()))
    assert 1e-4 < ratio <= 1.0
