"""The two implicit integrators checked against independent numpy/scipy implementations of their formulas."""
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import taichi_cloth as tc
from conftest import damping_matrix, spring_forces
from taichi_cloth.stability import stiffness_matrix


def deformed_scene(integrator, **opts):
    rng = np.random.default_rng(3)
    cloth = tc.ClothBuilder.grid((0.3, 0.3), (7, 7), "cotton", center=(0.0, 1.0, 0.0))
    sc = tc.Scene(cloth, integrator=integrator, dt=0.01, air_damping=0.3, precision="f64",
                  pins=[{"indices": [42]}], integrator_options=opts)
    x = cloth.positions + 0.004 * rng.standard_normal(cloth.positions.shape)
    x[42] = cloth.positions[42]
    v = 0.2 * rng.standard_normal(x.shape)
    v[42] = 0
    sc.state.set(x=x, v=v)
    return sc, x, v


def test_implicit_first_newton_iteration_solves_the_baraff_witkin_system():
    """The first Newton iteration of the implicit step (no line search) equals a direct sparse solve of A dv = b
    built independently with scipy: A = M (1 + h gamma) + h D + h^2 K, b = h (f0 - h K v0), all at x0."""
    h, gamma = 0.01, 0.3
    sc, x, v = deformed_scene("implicit", cg_tolerance=1e-12, cg_max_iterations=2000, newton_iterations=1,
                              line_search=False)
    d = sc.model.data
    free = ~sc.model.pinned
    f, u = spring_forces(d, x, v)
    f += d.mass[:, None] * np.array([0, -9.81, 0]) - gamma * d.mass[:, None] * v
    K = stiffness_matrix(x, d.springs, d.stiffness, d.rest_length)  # K = -df/dx
    D = damping_matrix(d, x)  # -df/dv: kd u u^T per spring, c I per mesh edge
    M = np.repeat(d.mass, 3) * (1 + h * gamma)
    A = np.diag(M) + h * D + h * h * K
    b = h * f.reshape(-1) - h * h * K @ v.reshape(-1)
    free3 = np.repeat(free, 3)
    dv = np.zeros(3 * d.n_particles)
    dv[free3] = spla.spsolve(sp.csr_matrix(A[np.ix_(free3, free3)]), b[free3])
    sc.step(1)
    np.testing.assert_allclose(sc.velocities() - v, dv.reshape(-1, 3), rtol=1e-7, atol=1e-10)
    assert sc.integrator.last_residual <= 1e-12


@pytest.mark.parametrize("opts", [{}, {"jv_term": True, "sweeps": 5}])
def test_approx_implicit_step_is_the_jacobi_formula(opts):
    """Hsiao 2006 eq. (2) written out in numpy: dv~ = h f / (m + h^2 K);
    dv = (h f + h^2 sum_j k_ij dv~_j) / (m + h^2 K), and more sweeps (with the h J~ v term) keep iterating the same
    Jacobi map. No warning is expected here (no filter: one would show)."""
    h, gamma = 0.01, 0.3
    sc, x, v = deformed_scene("approx-implicit", **opts)
    d = sc.model.data
    f, _ = spring_forces(d, x, v)
    f += d.mass[:, None] * np.array([0, -9.81, 0]) - gamma * d.mass[:, None] * v
    a, b = d.springs[:, 0], d.springs[:, 1]
    W = sp.coo_matrix((np.concatenate([d.stiffness, d.stiffness]), (np.concatenate([a, b]), np.concatenate([b, a]))),
                      shape=(d.n_particles,) * 2).tocsr()
    Ksum = np.asarray(W.sum(axis=1)).ravel()
    rhs = h * f
    if opts.get("jv_term"):
        rhs += h * h * (W @ v - Ksum[:, None] * v)
    diag = (d.mass + h * h * Ksum)[:, None]
    free = ~sc.model.pinned[:, None]
    dv = np.zeros_like(x)
    for _ in range(opts.get("sweeps", 2)):
        dv = (rhs + h * h * (W @ dv)) / diag * free
    sc.step(1)
    np.testing.assert_allclose(sc.velocities() - v, dv, rtol=1e-10, atol=1e-13)
