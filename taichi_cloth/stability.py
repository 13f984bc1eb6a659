"""Step-size theory (docs/algorithms.md, step limits): the largest stable step of an explicit integrator on a model.

The highest linear frequency omega_max of a cloth sets the explicit integrators' step. Three ways to get it:
  omega_max_estimate   Lanczos iterations on M^-1/2 K M^-1/2 at the cloth's positions (matrix-free, O(steps x
                       springs)), plus its residual bound and a 1 % margin: within a few per cent of the exact value
                       and above it. The engine's (step guard, dt = "auto", Scene.stable_dt).
  omega_max_bound      Gershgorin, sqrt(max_i 2 sum_j k_ij / m_i) over free particles: always an upper bound, but
                       1.6-1.8x above the exact value on cloth sheets (it caps the estimate).
  omega_max_exact      dense eigenvalues of the same matrix, for small models (tests and the stability study).
Damping enters through each integrator's closed-form condition (`Integrator.is_stable`).
`highest_mode` gives the shape of the highest mode, on which taichi_cloth.stability_probes measures the critical step
by simulation.
"""
from __future__ import annotations

import numpy as np


def stable_dt(integrator_cls, model, air_damping: float, safety: float = 1.0, omega: float | None = None) -> float | None:
    """The largest step [s] the linear theory guarantees stable for `integrator_cls` on `model`, times
    `safety`; None for an unconditionally stable integrator. `omega` [rad/s] defaults to the model's estimate
    (`Model.omega_max`, omega_max_estimate)."""
    if integrator_cls.unconditionally_stable:
        return None
    omega = model.omega_max() if omega is None else omega
    dt = integrator_cls.max_stable_dt(omega, air_damping, model.damping_ratio_max())
    return None if dt is None else safety * dt


#: Lanczos steps of omega_max_estimate, and the margin it adds on the frequency (the Ritz value approaches from below)
LANCZOS_STEPS = 40
OMEGA_MARGIN = 0.01


def stiffness_sum(data) -> np.ndarray:
    """(P,) sum of the spring constants' magnitudes at each particle of a ClothData [N/m] (a quadratic bending
    pair's constant may be negative: the Gershgorin bound counts |k|)."""
    return np.bincount(data.springs.reshape(-1), np.repeat(np.abs(data.stiffness), 2), minlength=data.n_particles)


def omega_max_bound(data, pinned: np.ndarray) -> float:
    """Gershgorin bound [rad/s], sqrt(max_i 2 sum_j k_ij / m_i) over the particles not `pinned` ((P,) bool)."""
    free = ~np.asarray(pinned, dtype=bool)
    if not free.any():
        return 0.0
    return float(np.sqrt(np.max(2.0 * stiffness_sum(data)[free] / data.mass[free])))


def omega_max_estimate(data, pinned: np.ndarray, positions: np.ndarray | None = None,
                       steps: int = LANCZOS_STEPS) -> float:
    """Highest linear frequency [rad/s] of the free particles of a ClothData at `positions` (default: its own),
    estimated by `steps` Lanczos iterations (full reorthogonalisation, a fixed seed) on M^-1/2 K M^-1/2, K the
    stiffness matrix of `stiffness_matrix` applied matrix-free. Returns sqrt(theta + r) (1 + OMEGA_MARGIN), theta the
    largest Ritz value and r = |beta_k s_k| its residual, capped by the Gershgorin bound: the Ritz value approaches
    the top of the spectrum from below, the residual and the margin put the estimate above it. 0 if every particle
    is pinned. About 0.1 s for 16k particles."""
    free = ~np.asarray(pinned, dtype=bool)
    if not free.any() or data.n_springs == 0:
        return 0.0
    x = data.positions if positions is None else np.asarray(positions, dtype=np.float64)
    a, b = data.springs[:, 0], data.springs[:, 1]
    d = x[b] - x[a]
    length = np.maximum(np.linalg.norm(d, axis=1), 1e-300)
    u = d / length[:, None]
    geo = np.maximum(0.0, 1.0 - data.rest_length / length)
    axial, iso = data.stiffness * (1.0 - geo), data.stiffness * geo
    scale = np.where(free, 1.0 / np.sqrt(data.mass), 0.0)[:, None]  # M^-1/2, 0 on pinned particles
    P = data.n_particles

    def apply(q):  # (M^-1/2 K M^-1/2) q for q (P, 3)
        y = scale * q
        dq = y[a] - y[b]
        f = axial[:, None] * u * np.einsum("si,si->s", u, dq)[:, None] + iso[:, None] * dq
        out = np.stack([np.bincount(a, f[:, c], minlength=P) - np.bincount(b, f[:, c], minlength=P)
                        for c in range(3)], axis=1)
        return scale * out

    q = np.random.default_rng(0).standard_normal((P, 3)) * free[:, None]
    q /= np.linalg.norm(q)
    basis, alphas, betas = [], [], []
    for _ in range(min(steps, 3 * int(free.sum()))):
        basis.append(q)
        w = apply(q)
        alphas.append(float(np.vdot(w, q)))
        Q = np.stack([v.ravel() for v in basis])
        w = w.ravel()
        for _ in range(2):  # full reorthogonalisation, twice ("twice is enough")
            w = w - Q.T @ (Q @ w)
        beta = float(np.linalg.norm(w))
        betas.append(beta)
        if beta <= 1e-12 * max(abs(alphas[-1]), 1e-300):
            break  # an invariant subspace: the Ritz values are exact
        q = (w / beta).reshape(P, 3)
    T = np.diag(alphas) + np.diag(betas[:-1], 1) + np.diag(betas[:-1], -1)
    theta, s = np.linalg.eigh(T)
    top = theta[-1] + abs(betas[-1] * s[-1, -1])
    return float(min(np.sqrt(max(top, 0.0)) * (1.0 + OMEGA_MARGIN), omega_max_bound(data, pinned)))


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
