"""Numbers printed in the paper (Routh, Das, Das, Pan), used as independent references."""

import numpy as np

# eq. 20: F_l, G_l at h = 0.1 s (4 decimals as printed)
EQ20_F = np.array([
    [[0.6703, -0.0018], [0.0294, 0.5134]],
    [[0.6703, -0.0015], [0.0378, 0.3678]],
    [[0.6702, -0.0010], [0.0502, 0.1353]],
])
EQ20_G = np.array([[[0.1648], [0.0035]], [[0.1648], [0.0048]], [[0.1648], [0.0073]]])

# eq. 21 as printed; 0.671 for F_2 is a typo (eq. 20's own F_2 has 0.6701)
EQ21_EIG = [(0.67, 0.5137), (0.671, 0.368), (0.6701, 0.1354)]

# eq. 23 (h = 0.1) and eq. 24 (h = 0.2): K_1, K_2, K_3 after ten CCL iterations
EQ23_GAINS = np.array([[[-4.0726, -0.0823]], [[0.0024, 0.0375]], [[0.0006, 0.0114]]])
EQ24_GAINS = np.array([[[-1.6351, -0.0225]], [[0.0013, 0.0097]], [[0.0001, 0.0015]]])
# eq. 22: the paper's Step 1 gains at h = 0.1
EQ22_GAINS = np.array([[[-4.0718, -0.0745]], [[0.0019, 0.0281]], [[0.0006, 0.0132]]])


def interval_matrix_by_stepping(F, G, gains, eta):
    """A_{l,eta}(K) by running the buffer logic on the unit vectors (independent of solver.network)."""
    n = F.shape[0]
    cols = []
    for j in range(n):
        x0 = np.eye(n)[:, j]
        x = x0.copy()
        for q in range(1, eta + 1):
            x = F @ x + G @ (gains[q - 1] @ x0)
        cols.append(x)
    return np.column_stack(cols)


def augmented_by_hand(A, n_drop):
    """Phi of eq. 10 built directly from its printed block pattern."""
    n = A.shape[0]
    rows = []
    for i in range(n_drop):
        row = []
        for j in range(n_drop):
            if i == 0 and j == 0:
                row.append(A)
            elif i >= 1 and j == i - 1:
                row.append(np.eye(n))
            else:
                row.append(np.zeros((n, n)))
        rows.append(row)
    return np.block(rows)


def theorem1_holds(F_list, G_list, gains, P):
    """Independent float64 check of Theorem 1: P > 0 and Phi^T P Phi - P < 0 for every (l, eta)."""
    n_drop = gains.shape[0]
    if np.linalg.eigvalsh(P)[0] <= 0:
        return False, -np.inf
    worst = np.inf
    for F, G in zip(F_list, G_list):
        for eta in range(1, n_drop + 1):
            Phi = augmented_by_hand(interval_matrix_by_stepping(F, G, gains, eta), n_drop)
            M = Phi.T @ P @ Phi - P
            worst = min(worst, -np.linalg.eigvalsh(0.5 * (M + M.T))[-1])
    return worst > 0, worst
