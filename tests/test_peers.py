"""`bench peers`: Taichi's shipped mass-spring example, run headless, against the same physics in our engine.

The example and our `explicit` integrator are the same scheme (symplectic Euler) on the same forces, except that
the example updates velocities in place inside its parallel spring loop (its dashpot term reads some neighbours'
updated velocities), integrates drag as exp(-drag dt) and handles the ball by velocity projection only. Those
differences are all first order in dt, so the test checks what that implies on a 12 x 12 sheet started stretched
(5 % along x) and wavy (2 cm), so that springs and dashpots work from the first step, 15 cm lower than the
example's start so that it reaches the ball sooner (the example's start height is not part of its kernel):
  - the distance between the two trajectories halves when dt halves (ratio 0.35..0.65; measured 0.49 before
    contact and 0.45-0.48 on the ball), so both converge to the same motion; with the ball 1 % larger on our side
    the ratio on the ball is 0.94-0.98, with the drag 10 % higher 0.84-0.91;
  - Richardson-extrapolating both (2 x(dt/2) - x(dt)) cancels those first-order terms: what is left before
    contact is second order plus float32 round-off, measured 4.5e-5 m against 2.8 cm of internal motion. The bound
    1e-4 m fails on a wrong constant: with spring_Y 1 % too high our side is 1.4e-4 m off, the dashpot 2 % too
    high 2.7e-4 m, the drag 10 % too high 1.9e-4 m (gravity 0.1 % off, 7.5e-5 m, passes: free fall is tested
    elsewhere).
Never needs Warp: its same-physics check runs only where warp-lang 1.9.1 is installed.
"""
import importlib.util

import numpy as np
import pytest

from benchmarks.accuracy import run_sampled
from benchmarks.peer_taichi_example import (ExamplePhysics, ExampleUnavailable, TaichiExample, example_path,
                                          headless_source, run_example)

pytestmark = pytest.mark.slow  # each runs Taichi's example and our engine against a reference (tens of seconds)

N = 12
DTS = (5e-5, 2.5e-5)  # [s] below our stable step at n = 12 (6.7e-5 s: the dashpots dominate)
FREE_TIMES = np.linspace(0.005, 0.1, 20)  # [s] before contact (the sheet meets the ball near t = 0.16 s)
CONTACT_TIMES = np.array([0.2, 0.23])  # [s] on the ball
DROP = 0.15  # [m] below the example's start height


def perturbed_start(physics: ExamplePhysics, drop: float = DROP) -> np.ndarray:
    """(P,3) [m]: the example's flat start, `drop` [m] lower, stretched 5 % along x and with a 2 cm wave in y."""
    x = physics.start_positions((0.5 * physics.quad_size, 0.5 * physics.quad_size))
    x[:, 1] -= drop
    n = physics.n
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    u, w = (i / (n - 1)).ravel(), (j / (n - 1)).ravel()
    x[:, 1] += 0.02 * np.sin(np.pi * u) * np.sin(2 * np.pi * w)
    x[:, 0] += 0.05 * (u - 0.5)
    return x


def _example_or_skip(n, dt):
    try:
        return TaichiExample(n, dt)
    except ExampleUnavailable as err:  # another taichi version: the bench skips it too
        pytest.skip(str(err))


@pytest.fixture(scope="module")
def runs():
    """Positions (S,P,3) of the shipped example and of our explicit integrator at both steps, from the perturbed
    start, sampled at FREE_TIMES + CONTACT_TIMES."""
    physics = ExamplePhysics(N)
    start = perturbed_start(physics)
    times = np.concatenate([FREE_TIMES, CONTACT_TIMES])
    out = {"physics": physics, "start": start}
    scene = physics.scene("explicit", DTS[0], positions=start)
    for dt in DTS:
        example = _example_or_skip(N, dt)
        assert example.physics == physics  # the constants we reproduce are the shipped file's
        traj, _ = run_example(N, dt, times, start=start, example=example)
        assert traj.stable, traj.message
        scene.dt = dt
        scene.reset()
        ours = run_sampled(scene, times)
        assert ours.stable, ours.message
        out[dt] = (traj.positions, ours.positions)
    return out


def test_before_contact_same_motion_to_first_order(runs):
    free = slice(0, len(FREE_TIMES))
    start = runs["start"]
    ex = {dt: runs[dt][0][free] for dt in DTS}
    us = {dt: runs[dt][1][free] for dt in DTS}
    # the springs work: the shape changes by centimetres relative to the falling centre of mass
    shape = us[DTS[1]] - us[DTS[1]].mean(axis=1, keepdims=True)
    assert np.linalg.norm(shape - (start - start.mean(axis=0)), axis=2).max() > 0.02
    d = [np.linalg.norm(ex[dt] - us[dt], axis=2).max() for dt in DTS]
    assert d[0] < 2e-3, d
    assert 0.35 < d[1] / d[0] < 0.65, d  # first order: halves with dt
    richardson = np.linalg.norm((2 * ex[DTS[1]] - ex[DTS[0]]) - (2 * us[DTS[1]] - us[DTS[0]]), axis=2).max()
    assert richardson < 1e-4, richardson


def test_on_the_ball_same_motion_to_first_order(runs):
    physics = runs["physics"]
    contact = slice(len(FREE_TIMES), None)
    for dt in DTS:
        for x in runs[dt]:  # both rest on the ball: some particles within 1 mm of its surface, none deep inside
            r = np.linalg.norm(x[contact] - np.asarray(physics.ball_center), axis=2) - physics.ball_radius
            assert (r.min(axis=1) > -1e-3).all() and (np.abs(r) < 1e-3).any(axis=1).all()
    d = [np.linalg.norm(runs[dt][0][contact] - runs[dt][1][contact], axis=2).max(axis=1) for dt in DTS]
    ratio = d[1] / d[0]
    assert (ratio > 0.35).all() and (ratio < 0.65).all(), (d, ratio)


def test_cloth_reproduces_the_example():
    """Spring counts, constants and our numpy energy against the engine's own measurement."""
    p = ExamplePhysics(7)
    cloth = p.cloth()
    n = p.n
    assert cloth.n_particles == n * n and np.all(cloth.mass == 1.0)
    # |di| + |dj| <= 2: structural 2n(n-1), diagonal 2(n-1)^2, skip-one 2n(n-2)
    assert cloth.n_springs == 2 * n * (n - 1) + 2 * (n - 1) ** 2 + 2 * n * (n - 2)
    q = 1.0 / n
    L = np.linalg.norm(cloth.positions[cloth.springs[:, 1]] - cloth.positions[cloth.springs[:, 0]], axis=1)
    np.testing.assert_allclose(cloth.rest_length, L, rtol=1e-12)
    assert set(np.round(cloth.rest_length / q, 9)) == {1.0, 2.0, round(np.sqrt(2.0), 9)}
    np.testing.assert_allclose(cloth.stiffness * cloth.rest_length, 3e4, rtol=1e-12)
    np.testing.assert_allclose(cloth.damping, 1e4 * q, rtol=1e-12)
    # implicit: its velocity is at the positions' time, as the numpy energy reads it (the explicit family's is
    # measured half a step ahead)
    scene = p.scene("implicit", 1e-5, precision="f64", positions=perturbed_start(p))
    scene.step(20)
    m = scene.measure()
    assert p.energy(scene.positions(), scene.velocities()) == pytest.approx(m.total, rel=1e-9)
    assert p.max_strain(scene.positions()) == pytest.approx(m.max_strain, rel=1e-9)


def test_substitutions_are_checked():
    src = example_path().read_text() if example_path().is_file() else None
    if src is None:
        pytest.skip("the taichi wheel ships no mass_spring_3d_ggui.py")
    out = headless_source(16, 1e-4, src)
    assert "ti.init(" not in out and "\nn = 16\n" in out and "\ndt = 0.0001\n" in out
    with pytest.raises(ExampleUnavailable, match="dt = 4e-2 / n"):
        headless_source(16, 1e-4, src.replace("dt = 4e-2 / n", "dt = 3e-2 / n"))
    with pytest.raises(ExampleUnavailable, match="ti.init"):
        headless_source(16, 1e-4, src.replace("ti.init(arch=arch)", "ti.init(arch=arch)\nti.init(arch=arch)"))


@pytest.mark.skipif(importlib.util.find_spec("warp") is None, reason="warp-lang is not installed (optional)")
def test_warp_same_physics_matches_ours_before_contact():
    """Warp's SemiImplicitIntegrator is our explicit scheme: before contact (no ball force) the two agree to float32
    round-off (measured 6e-8 m), where a wrong sign of gravity or a missing drag would be centimetres off."""
    from benchmarks.peer_warp import WarpSamePhysics, run_same_physics, warp_status

    if warp_status()[0] is not None:
        pytest.skip(warp_status()[0])
    physics = ExamplePhysics(8)
    start = perturbed_start(physics)
    times = np.array([0.02, 0.04])
    dt = 4e-5
    sim = WarpSamePhysics(physics, "semi-implicit", dt, start=start)
    theirs = run_same_physics(sim, times, start)
    ours = run_sampled(physics.scene("explicit", dt, positions=start), times)
    assert theirs.stable and ours.stable
    assert np.linalg.norm(theirs.positions - ours.positions, axis=2).max() < 1e-5
    np.testing.assert_allclose(theirs.energy, ours.energy, rtol=1e-4)
