"""The B-P law for shear as the peer scripts integrate it, independently of
mrbp: explicit Euler with equal sub-steps per sample interval, the strain
linear between samples, from rest (numba)."""
import math

import numba
import numpy as np

# the flow rule's limiting inelastic rate (1/s), as the paper's
D0 = 1.0e4


@numba.njit(cache=False, fastmath=False)
def bp_path(theta, t, gamma, substeps):
    """The stress at every sample for θ = (G, R0, R1, D1, m1, m2, n); NaN
    or inf from where the integration fails."""
    g, r0, r1, d1, m1, m2, n = theta
    out = np.empty(len(t))
    tau, w = 0.0, 0.0
    out[0] = tau
    c = 0.5 * (n + 1.0) / n
    for k in range(len(t) - 1):
        h = (t[k + 1] - t[k]) / substeps
        rate = (gamma[k + 1] - gamma[k]) / (t[k + 1] - t[k])
        for _ in range(substeps):
            z = r1 + (r0 - r1) * math.exp(-m1 * w) + d1 * (1.0 - math.exp(-m2 * w))
            a = abs(tau)
            gi = 0.0
            if a > 0.0:
                q = (z / (math.sqrt(3.0) * a)) ** (2.0 * n)
                gi = 2.0 * D0 * math.exp(-c * q)
                if tau < 0.0:
                    gi = -gi
            tau_new = tau + h * g * (rate - gi)
            w += h * tau * gi
            tau = tau_new
        out[k + 1] = tau
    return out
