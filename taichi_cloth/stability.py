"""Step-size theory (docs/algorithms.md, step limits): the largest stable step of an explicit integrator on a model.

omega_max is bounded by Gershgorin, sqrt(max_i 2 sum_j k_ij / m_i) over free particles (cheap, always
valid, used by the engine); `omega_max_exact` computes it from the linearised stiffness at the rest
shape (dense eigenvalues, for small models: tests and the stability study). Damping enters through each
integrator's closed-form condition (`Integrator.is_stable`).
`highest_mode` gives the shape of the highest mode, on which taichi_cloth.bench.probes measures the critical step
by simulation.
"""
from __future__ import annotations

import numpy as np


def stable_dt(integrator_cls, model, air_damping: float, safety: float = 1.0, omega: float | None = None) -> float | None:
    """The largest step [s] the linear theory guarantees stable for `integrator_cls` on `model`, times
    `safety`; None for an unconditionally stable integrator. `omega` [rad/s] defaults to the Gershgorin bound."""
    omega = model.omega_max_bound() if omega is None else omega
    dt = integrator_cls.max_stable_dt(omega, air_damping, model.damping_ratio_max())
    return None if dt is None else safety * dt


def stiffness_matrix(positions: np.ndarray, springs: np.ndarray, stiffness: np.ndarray, rest_length: np.ndarray) -> np.ndarray:
    """Dense (3P,3P) stiffness matrix K = -df/dx of a spring network at `positions` (BW98 Jacobians,
    with the geometric term clamped at 0 for compressed springs)."""
    P = len(positions)
    K = np.zeros((3 * P, 3 * P))
    d = positions[springs[:, 1]] - positions[springs[:, 0]]
    length = np.linalg.norm(d, axis=1)
    u = d / np.maximum(length, 1e-300)[:, None]
    geo = np.maximum(0.0, 1.0 - rest_length / np.maximum(length, 1e-300))
    blocks = stiffness[:, None, None] * (np.einsum("si,sj->sij", u, u) * (1 - geo)[:, None, None]
                                         + geo[:, None, None] * np.eye(3))
    a, b = springs[:, 0], springs[:, 1]
    c = np.arange(3)
    for i, j, sign in ((a, a, 1.0), (b, b, 1.0), (a, b, -1.0), (b, a, -1.0)):
        rows = (3 * i)[:, None, None] + c[None, :, None]
        cols = (3 * j)[:, None, None] + c[None, None, :]
        np.add.at(K, (np.broadcast_to(rows, blocks.shape), np.broadcast_to(cols, blocks.shape)), sign * blocks)
    return K


def _mass_scaled_free(model, positions):
    """(free dof mask (3P,) bool, M^-1/2 on the free dofs, M^-1/2 K M^-1/2 on the free dofs)."""
    d = model.data
    x = d.positions if positions is None else positions
    K = stiffness_matrix(x, d.springs, d.stiffness, d.rest_length)
    free = np.repeat(~model.pinned, 3)
    s = 1.0 / np.sqrt(np.repeat(d.mass, 3))[free]
    return free, s, s[:, None] * K[np.ix_(free, free)] * s[None, :]


def highest_mode(model, positions: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """The highest linear mode of the free particles at `positions` (default: rest shape): its frequency
    [rad/s] and its shape, a (P,3) float64 displacement scaled to a largest entry of 1 (zero on pinned
    particles). Dense, as omega_max_exact."""
    free, s, A = _mass_scaled_free(model, positions)
    lam, vec = np.linalg.eigh(A)
    shape = np.zeros(len(free))
    shape[free] = s * vec[:, -1]  # back from mass-scaled coordinates: x = M^-1/2 y
    shape /= np.abs(shape).max()
    return float(np.sqrt(max(lam[-1], 0.0))), shape.reshape(-1, 3)


def omega_max_exact(model, positions: np.ndarray | None = None) -> float:
    """Highest linear frequency [rad/s] of the free particles at `positions` (default: rest shape), from
    the generalised eigenproblem K v = w^2 M v with pinned particles removed. Dense: use for P < ~1000."""
    lam = np.linalg.eigvalsh(_mass_scaled_free(model, positions)[2])
    return float(np.sqrt(max(lam.max(), 0.0)))
