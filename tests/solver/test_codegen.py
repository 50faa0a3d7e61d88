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

    def __init__(self, lib, prefix, m, n_drop):
        self.m, self.n_drop = m, n_drop
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
        x = np.ascontiguousarray(x, dtype=np.float64)
        out = np.empty(self.n_drop * self.m)
        self.fn["packet"](x.ctypes.data_as(ctypes.c_void_p), out.ctypes.data_as(ctypes.c_void_p))
        return out

    def receive(self, packet, stamp):
        packet = np.ascontiguousarray(packet, dtype=np.float64)
        self.fn["buffer_receive"](self.mem, packet.ctypes.data_as(ctypes.c_void_p), stamp % 2**32)

    def output(self):
        u = np.empty(self.m)
        self.fn["buffer_output"](self.mem, u.ctypes.data_as(ctypes.c_void_p))
        return u


class ModelBuffer:
    """Independent reference: keeps every packet, picks the newest stamp at each output."""

    def __init__(self, K, exhausted, now=0):
        self.K, self.exhausted, self.now, self.got, self.ages = K, exhausted, now, [], []

    def receive(self, x, stamp):
        if stamp <= self.now:  # a stamp ahead of the clock is refused
            self.got.append((stamp, np.array(x)))

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
                 "void ncs_buffer_receive(ncs_buffer_t *b, const double packet[], uint32_t stamp);"):
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


def test_metadata_cannot_close_the_comment():
    text = export_c(EQ23_GAINS, 3, metadata={"id": "x */ int evil; /*"})["ncs_controller.h"]
    assert "x * / int evil" in text and "*/ int evil" not in text
