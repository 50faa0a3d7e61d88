"""OpenAPI examples. The paper's example (eq. 19, h = 0.1, N_drop = 3) comes first."""

PAPER_PLANT = {
    "kind": "continuous",
    "A": [
        [[-4.0, -0.03], [0.5, -6.667]],
        [[-4.0, -0.03], [0.75, -10.0]],
        [[-4.0, -0.03], [1.5, -20.0]],
    ],
    "B": [[[2.0], [0.0]], [[2.0], [0.0]], [[2.0], [0.0]]],
    "sampling_period": 0.1,
}

PAPER_GAINS_H01 = [[[-4.0726, -0.0823]], [[0.0024, 0.0375]], [[0.0006, 0.0114]]]  # eq. 23

DESIGN_EXAMPLES = {
    "paper_lmi": {
        "summary": "Paper example (eq. 19, h = 0.1), exact convex design",
        "value": {"plant": PAPER_PLANT, "n_drop": 3, "method": "lmi"},
    },
    "named_one_mode": {
        "summary": "One plant mode (still a list: [A]), named states and inputs with units, a label",
        "value": {"label": "motor rig A", "n_drop": 3,
                  "plant": {"kind": "continuous", "sampling_period": 0.1,
                            "A": [[[-4.0, -0.3], [5.0, -6.667]]], "B": [[[2.0], [0.0]]],
                            "state_names": ["i_a", "omega"], "input_names": ["v_a"],
                            "units": {"i_a": "A", "omega": "rad/s", "v_a": "V"}}},
    },
    "paper_delays": {
        "summary": "Paper example on a network with late and reordered packets (one sample late at most)",
        "value": {"plant": PAPER_PLANT, "method": "lmi", "network": {"kind": "delays", "max_delay": 1, "n_drop": 2}},
    },
    "paper_ccl": {
        "summary": "Paper example with the paper's CCL iteration",
        "value": {"plant": PAPER_PLANT, "n_drop": 3, "method": "ccl", "options": {"max_iter": 50}},
    },
    "dc_motor": {
        "summary": "DC motor from physical parameters (Table I), three inertias",
        "value": {"plant": {"kind": "dc_motor", "inertias": [0.03, 0.02, 0.01], "sampling_period": 0.1,
                            "resistance": 2.0, "inductance": 0.5, "torque_constant": 0.15,
                            "back_emf_constant": 0.15, "damping": 0.2},
                  "n_drop": 3, "method": "lmi"},
    },
    "discrete": {
        "summary": "Discrete-time family (eq. 20 at h = 0.1)",
        "value": {"plant": {"kind": "discrete",
                            "F": [[[0.6703, -0.0018], [0.0294, 0.5134]], [[0.6703, -0.0015], [0.0378, 0.3678]],
                                  [[0.6702, -0.0010], [0.0502, 0.1353]]],
                            "G": [[[0.1648], [0.0035]], [[0.1648], [0.0048]], [[0.1648], [0.0073]]],
                            "sampling_period": 0.1},
                  "n_drop": 3, "method": "lmi"},
    },
}

ANALYSIS_EXAMPLES = {
    "paper_eq23": {
        "summary": "The paper's gains (eq. 23) on the paper's plant",
        "value": {"plant": PAPER_PLANT, "n_drop": 3, "gains": PAPER_GAINS_H01},
    },
}

CHANNEL_EXAMPLES = {
    "paper_gilbert_elliott": {
        "summary": "The paper's gains over a Gilbert-Elliott link, zero input when the buffer runs dry",
        "value": {"plant": PAPER_PLANT, "n_drop": 3, "gains": PAPER_GAINS_H01,
                  "channel": {"kind": "gilbert_elliott", "p_gb": 0.05, "p_bg": 0.3, "loss_good": 0.01,
                              "loss_bad": 0.8},
                  "exhausted": "zero", "weights": {"Q": [[1, 0], [0, 1]], "R": [[1]]}},
    },
    "paper_late_packets": {
        "summary": "The same link delivering 30 % of its packets a sample late; how often a (2, 5) window breaks",
        "value": {"plant": PAPER_PLANT, "n_drop": 3, "gains": PAPER_GAINS_H01,
                  "channel": {"kind": "gilbert_elliott", "p_gb": 0.05, "p_bg": 0.3, "loss_good": 0.01,
                              "loss_bad": 0.8, "delays": [0.7, 0.3]},
                  "exhausted": "zero", "weights": {"Q": [[1, 0], [0, 1]], "R": [[1]]},
                  "network": {"kind": "weakly_hard", "misses": 2, "window": 5, "n_drop": 3}},
    },
}

SIMULATION_EXAMPLES = {
    "paper_fig3": {
        "summary": "Fig. 3-like run: paper plant and gains, x0 = [-3, 2]",
        "value": {"plant": PAPER_PLANT, "n_drop": 3, "gains": PAPER_GAINS_H01, "x0": [-3.0, 2.0],
                  "steps": 100, "seed": 42},
    },
    "paper_weakly_hard": {
        "summary": "Paper plant and gains, ages drawn from a weakly-hard (2, 5) network",
        "value": {"plant": PAPER_PLANT, "gains": PAPER_GAINS_H01, "x0": [-3.0, 2.0], "steps": 100, "seed": 42,
                  "network": {"kind": "weakly_hard", "misses": 2, "window": 5, "n_drop": 3}},
    },
}


MARGIN_EXAMPLES = {
    "largest_n_drop": {
        "summary": "Largest n_drop of the paper example with the hold-last-input baseline",
        "value": {"plant": PAPER_PLANT, "search": "n_drop", "method": "lmi", "n_drop_max": 8,
                  "options": {"scheme": "hold"}},
    },
    "largest_sampling_period": {
        "summary": "Largest sampling period of a double integrator + oscillator at n_drop = 4",
        "value": {"plant": {"kind": "continuous",
                            "A": [[[0.0, 1.0], [0.0, 0.0]], [[0.0, 1.0], [-1.0, 0.0]]],
                            "B": [[[0.0], [1.0]], [[0.0], [1.0]]], "sampling_period": 0.1},
                  "search": "sampling_period", "n_drop": 4, "h_min": 0.05, "h_max": 3.0, "tol": 0.01,
                  "options": {"scheme": "hold"}},
    },
    "grid": {
        "summary": "Design grid over (h, n_drop) for the paper example",
        "value": {"plant": PAPER_PLANT, "search": "grid",
                  "points": [{"sampling_period": 0.1, "n_drop": 3}, {"sampling_period": 0.2, "n_drop": 3},
                             {"sampling_period": 0.5, "n_drop": 6}]},
    },
}
