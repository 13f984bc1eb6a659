"""Energy-safe large steps: the implicit step minimises the incremental potential by Newton iterations with a line
search, and takes another iteration whenever the iterate has gained energy, so that a step never adds energy to a
cloth released from rest. One linearised solve per step (the classical implicit Euler) did, at 1/30 s."""
import numpy as np
import pytest

from taichi_cloth.study_scenes import SCENES, energy_scale


def largest_rise_of_the_step(scene_name: str, dt: float, seconds: float, **options) -> tuple[float, object]:
    """The study scene on 4-8 level 4 (145 particles): the largest rise of the total energy [J / (weight x size)]
    that the integrator's step alone made (the colliders' projection after it is measured apart)."""
    spec = SCENES[scene_name]
    scale = energy_scale(spec)
    sc = spec.build(4, 3, "implicit", dt, options={"cg_tolerance": 1e-2, **options})
    rises = []
    for _ in range(int(round(seconds / dt))):
        before = sc.measure().total
        sc.substep(dt, observe=lambda: rises.append((sc.measure().total - before) / scale))
    return max(rises), sc


@pytest.mark.slow
@pytest.mark.parametrize("scene_name", ["sphere", "hanging"])
def test_a_frame_sized_step_never_gains_energy(scene_name):
    """h = 1/30 s: a sheet dropped onto the ball (contacts from the fifth step on), and one held by an edge."""
    worst, sc = largest_rise_of_the_step(scene_name, 1 / 30, 1.0)
    assert worst <= 0.0, worst
    assert sc.integrator.stats["newton_iterations"] > 30  # it did take extra iterations where it had to
    if scene_name == "sphere":  # and shorter steps on contact (evaluated only when the full one fails)
        assert sc.integrator.stats["line_search_cuts"] > 0


@pytest.mark.slow
def test_one_linearised_solve_per_step_gains_energy_on_the_ball():
    """The same drop with the classical single solve (one Newton iteration, no line search) gains energy on
    contact: what the Newton iterations are for."""
    worst, _ = largest_rise_of_the_step("sphere", 1 / 30, 0.5, newton_iterations=1, line_search=False)
    assert worst > 0.1, worst


def test_smooth_motion_takes_one_newton_iteration():
    """A sheet swinging down from one edge at 1/60 s: every step keeps to one Newton iteration (no energy
    gained), so the safety costs nothing where it is not needed."""
    worst, sc = largest_rise_of_the_step("hanging", 1 / 60, 0.5)
    steps = int(round(0.5 * 60))
    assert worst <= 0.0 and sc.integrator.stats["newton_iterations"] <= steps + 2


def test_newton_converge_iterates_every_step_to_the_tolerance():
    """newton_converge: the same swinging sheet takes at least two Newton iterations per step (the first one's
    decrement is what the tolerance is relative to), where the default took one."""
    worst, sc = largest_rise_of_the_step("hanging", 1 / 60, 0.5, newton_converge=True)
    steps = int(round(0.5 * 60))
    assert worst <= 0.0 and sc.integrator.stats["newton_iterations"] >= 2 * steps, sc.integrator.stats


def test_without_a_warm_start_a_step_depends_on_the_state_alone():
    """warm_start = false: CG starts from zero, so a step taken from a copied state after the integrator forgot its
    history is the same step (to round-off); with the warm start the carried-over velocity change makes it
    another one (the difference is what a loose tolerance lets through, and what kept a resting hem fluttering)."""
    dt, apart = 1 / 60, {}
    for warm in (False, True):
        sc = SCENES["hanging"].build(4, 3, "implicit", dt, precision="f64",
                                     options={"cg_tolerance": 1e-2, "preconditioner": "jacobi", "warm_start": warm})
        for _ in range(20):
            sc.integrator.step(sc.state, sc.contacts, dt)
        x, v = sc.state.positions(), sc.state.velocities()
        sc.integrator.step(sc.state, sc.contacts, dt)
        after_history = sc.state.positions()
        sc.state.set(x=x, v=v)
        sc.integrator.reset()
        sc.integrator.step(sc.state, sc.contacts, dt)
        apart[warm] = np.abs(sc.state.positions() - after_history).max()
    assert apart[False] < 1e-12, apart
    assert apart[True] > 1e-6, apart
