"""The lean explicit step: its stable step from a Lanczos estimate of the highest frequency (checked against a dense
eigensolve), and its fused substeps (a frame's steps in few launches) checked against the unfused step."""
import numpy as np
import pytest

import taichi_cloth as tc
from taichi_cloth.builder import ClothBuilder
from taichi_cloth.stability import omega_max_bound, omega_max_estimate, omega_max_exact

from conftest import grid_top_corners


def jittered_sheet(n: int, seed: int):
    """An n x n cotton sheet with random masses (x0.2..x5) and stiffnesses (x0.5..x2) and a stretched, crumpled
    shape: the highest mode is not the regular grid's."""
    rng = np.random.default_rng(seed)
    data = ClothBuilder.grid((0.4, 0.4), (n, n), "cotton")
    data.mass = data.mass * rng.uniform(0.2, 5.0, data.n_particles)
    data.stiffness = data.stiffness * rng.uniform(0.5, 2.0, data.n_springs)
    data.positions = data.positions * 1.05 + rng.normal(0, 0.002, data.positions.shape)
    return data


@pytest.mark.parametrize("n, seed, pinned", [(6, 0, False), (10, 1, True), (16, 2, False), (16, 3, True)])
def test_the_frequency_estimate_lies_within_two_percent_above_the_exact_one(n, seed, pinned):
    data = jittered_sheet(n, seed)
    pins = np.zeros(data.n_particles, bool)
    if pinned:
        pins[grid_top_corners(n)] = True
    model = tc.Scene(data, integrator="implicit", dt=1e-3).model
    model.pin(np.nonzero(pins)[0])
    exact = omega_max_exact(model, data.positions)
    estimate = omega_max_estimate(data, pins)
    assert exact <= estimate <= 1.02 * exact, (estimate / exact)
    # Gershgorin stays above both, and well above: the step it allowed was too short
    assert omega_max_bound(data, pins) > 1.2 * exact
    assert model.omega_max() == pytest.approx(estimate)


def test_the_stable_step_follows_the_estimate_and_is_re_estimated_when_the_model_changes():
    scene = tc.Scene(ClothBuilder.grid((0.3, 0.3), (8, 8), "cotton"), integrator="explicit", dt=1e-5)
    cls, air, beta = type(scene.integrator), scene.forces.air_damping_value, scene.model.damping_ratio_max()
    for _ in range(2):
        exact = omega_max_exact(scene.model)
        assert cls.max_stable_dt(1.02 * exact, air, beta) <= scene.stable_dt <= cls.max_stable_dt(exact, air, beta)
        before = scene.stable_dt
        scene.model.set_stiffness(4.0 * scene.model.data.stiffness)  # omega doubles: the step shrinks
    assert scene.stable_dt < 0.6 * before


def drop_on_ball(n: int, fused: bool, integrator: str = "explicit", **extra):
    cloth = ClothBuilder.grid((0.5, 0.5), (n, n), "cotton", center=(0.02, 0.3, 0.01), plane="xz")
    return tc.Scene(cloth, integrator=integrator, dt=2e-4, integrator_options={"fused": fused}, air_damping=0.5,
                    colliders=[{"type": "sphere", "center": [0, 0, 0], "radius": 0.2},
                               {"type": "plane", "point": [0, -0.1, 0], "normal": [0, 1, 0]}], **extra)


@pytest.mark.parametrize("integrator, parallel", [("explicit", False), ("explicit", True), ("verlet", False),
                                                  ("central-difference", True)])
def test_fused_steps_give_the_unfused_trajectory(integrator, parallel, monkeypatch):
    if parallel:  # a cloth this small runs its loops in parallel only when told to
        monkeypatch.setenv("TAICHI_CLOTH_PARALLEL_FROM", "1")
    runs = []
    for fused in (True, False):
        scene = drop_on_ball(12, fused, integrator)
        assert scene.model.serial is not parallel
        assert scene.fused is fused
        scene.run(12, progress=False)  # 12 frames of 84 steps (fused: 10 launches of 8 and 4 of 1 when parallel)
        runs.append((scene.positions(), scene.velocities(), scene.state.t, scene.steps_taken))
    (x1, v1, t1, n1), (x2, v2, t2, n2) = runs
    assert (t1, n1) == (t2, n2)
    np.testing.assert_array_equal(x1, x2)  # bit for bit: the same operations in the same order
    np.testing.assert_array_equal(v1, v2)
    assert x1[:, 1].min() > -0.1  # it landed (on the ball and the floor), resolved in the fused update
    start = ClothBuilder.grid((0.5, 0.5), (12, 12), center=(0.02, 0.3, 0.01), plane="xz").positions
    assert np.abs(x1 - start).max() > 0.05


def test_steps_are_fused_only_where_nothing_between_them_needs_the_host():
    assert drop_on_ball(4, True).fused
    assert drop_on_ball(4, True, pins=[{"indices": [0]}]).fused  # fixed pins live in the inverse masses
    assert not drop_on_ball(4, True, pins=[{"indices": [0], "keyframes": [[0, 0, 0, 0], [1, 0, 0.1, 0]]}]).fused
    assert not drop_on_ball(4, True, wind={"velocity": [1, 0, 0]}).fused
    assert not drop_on_ball(4, True, stretch_limit={"max_strain": 0.1}).fused
    assert not tc.Scene(ClothBuilder.grid((0.3, 0.3), (4, 4)), integrator="implicit", dt=1e-3).fused
