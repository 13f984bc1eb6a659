"""Stability at the extremes: stiffness 1e1..1e7 N/m, steps 1e-5..1e-1 s, mass ratios 1..1e4.

The explicit schemes must run stable wherever their closed-form damped condition (docs/algorithms.md, step limits,
evaluated at the exact highest linear frequency) says so with a 10 % margin, and must be stopped with a
clean BlowUpError where the step is 1.5 x beyond it. The two implicit schemes must stay finite
everywhere (with a little damping). Nothing may ever produce NaN silently. One scene per integrator and
mass ratio is reused across the sweep (stiffness written to a field, dt passed as an argument), so the
whole sweep compiles each kernel once (taichi_cloth.stability_probes.probe_scene, shared with `bench stability`).

Where the theory is exact (a 1D chain, docs/algorithms.md) the critical step measured by bisection matches the
closed forms: sqrt(m/k) within 1 % undamped, 2/omega_max closer still, and the damped variants' conditions.
"""
import math

import numpy as np
import pytest

import taichi_cloth as tc
from clothbase.errors import EngineWarning
from taichi_cloth.stability_probes import (PROBE_AIR as AIR, PROBE_BETA as BETA, critical_step, probe_run,
                                          probe_scene, set_max_stiffness)
from taichi_cloth.stability import omega_max_exact

STIFFNESS = [1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7]
STEPS = [1e-5, 1e-4, 1e-3, 1e-2, 1e-1]
N_STEPS = 300


def assert_nan_is_reported(scene):
    """Nothing yields NaN silently: a non-finite coordinate raises a BlowUpError naming the integrator, the step
    and a suggested step (no larger than the stable bound for an explicit integrator)."""
    scene.reset()
    set_max_stiffness(scene.model, 1e3)
    scene.dt = 1e-3
    x = scene.model.data.positions.copy()
    x[7] = np.nan
    scene.state.set(x=x)
    with pytest.raises(tc.BlowUpError) as err:
        scene.step(2)
    e, name = err.value, scene.integrator.name
    assert e.integrator == name and e.step == 2 and "NaN" in e.reason
    assert name in str(e) and "by step 2" in str(e) and "suggested" in str(e)
    assert e.suggested_dt is not None and 0 < e.suggested_dt
    if scene.stable_dt is not None:
        assert e.suggested_dt <= scene.stable_dt


@pytest.mark.slow
@pytest.mark.parametrize("mass_ratio", [1.0, 1e4])
@pytest.mark.parametrize("integrator", ["explicit", "verlet", "central-difference"])
def test_explicit_schemes_follow_their_stability_bound(integrator, mass_ratio):
    scene = probe_scene(integrator, mass_ratio)
    cls = type(scene.integrator)
    rng = np.random.default_rng(0)
    checked = {"stable": 0, "unstable": 0}
    for k in STIFFNESS:
        set_max_stiffness(scene.model, k)
        omega = omega_max_exact(scene.model)
        beta = scene.model.damping_ratio_max()
        h_crit = cls.max_stable_dt(omega, AIR, beta)
        for dt in STEPS:
            if dt <= 0.9 * h_crit:
                m = probe_run(scene, k, dt, rng, steps=N_STEPS)  # raises BlowUpError if it went unstable
                assert m.nonfinite == 0 and math.isfinite(m.total)
                checked["stable"] += 1
            elif dt >= 1.5 * h_crit:
                with pytest.raises(tc.BlowUpError) as err:
                    probe_run(scene, k, dt, rng, steps=N_STEPS)
                text = str(err.value)
                assert integrator in text and "step" in text and "suggested stable step" in text
                assert err.value.suggested_dt is not None and err.value.suggested_dt < dt
                checked["unstable"] += 1
            else:  # inside the margin: either outcome, but never a silent NaN
                try:
                    m = probe_run(scene, k, dt, rng, steps=N_STEPS)
                    assert m.nonfinite == 0
                except tc.BlowUpError as err:
                    assert err.step > 0 and err.reason  # reported, not silent
    assert checked["stable"] >= 8 and checked["unstable"] >= 8  # the sweep really crossed the bound
    assert_nan_is_reported(scene)


@pytest.mark.slow
@pytest.mark.parametrize("mass_ratio", [1.0, 1e2, 1e4])
@pytest.mark.parametrize("integrator", ["approx-implicit", "implicit"])
def test_implicit_schemes_stay_finite_over_the_whole_sweep(integrator, mass_ratio):
    scene = probe_scene(integrator, mass_ratio)
    rng = np.random.default_rng(0)
    for k in STIFFNESS:
        for dt in STEPS:
            e0 = []
            # 60 steps: a growing mode of these one-step schemes shows within a few steps at large h w
            m = probe_run(scene, k, dt, rng, steps=60, initial=e0)
            assert m.nonfinite == 0
            # damped, no external force: no growth. The measured total of the one-step schemes wobbles by
            # O(h) between kinetic and elastic (seen: +1.1 % after 60 steps at k = 100 N/m, dt = 1e-4 s, back
            # to -2 % 240 steps later), so allow 2 %; a growing mode passes that within these steps
            assert m.total <= 1.02 * e0[0]
    assert_nan_is_reported(scene)


def test_gershgorin_bound_is_a_valid_lower_bound_on_the_critical_step():
    """The engine's cheap bound never promises more than the exact linear theory allows."""
    for ratio in (1.0, 1e4):
        scene = probe_scene("explicit", ratio)
        assert scene.model.omega_max_bound() >= omega_max_exact(scene.model)
        assert scene.stable_dt <= type(scene.integrator).max_stable_dt(omega_max_exact(scene.model), AIR, BETA)


def test_step_guard_refuses_or_warns():
    cloth = tc.ClothBuilder.grid((0.3, 0.3), (6, 6), "cotton")
    with pytest.raises(tc.SceneError, match="exceeds the stable step"):
        tc.Scene(cloth, integrator="explicit", dt=1e-2, step_guard="refuse")
    with pytest.warns(EngineWarning, match=r"dt = 0\.01 s exceeds the stable step .* of integrator 'explicit'"):
        scene = tc.Scene(cloth, integrator="explicit", dt=1e-2, step_guard="warn")
    assert scene.warnings and "exceeds the stable step" in scene.warnings[0]
    assert tc.Scene(cloth, integrator="approx-implicit", dt=1e-1, step_guard="refuse").stable_dt is None


# ---------------------------------------------------------------------- where the theory is exact: a 1D chain
# docs/algorithms.md, step limits: omega_max = 19.990 rad/s, sqrt(m/k) = 0.1 s
CHAIN_N, CHAIN_M, CHAIN_K = 50, 1.0, 100.0


def chain_scene(integrator: str, air_damping: float):
    """A free 1D chain of 50 equal 1 kg masses on 100 N/m springs, 1 m apart, no gravity, f64. Started on the
    highest mode it stays on the chain's axis, where the springs are exactly linear to first order."""
    chain = tc.ClothBuilder.chain(CHAIN_N, CHAIN_N - 1.0, CHAIN_M, CHAIN_K)
    return tc.Scene(chain, integrator=integrator, dt=0.05, gravity=(0, 0, 0), air_damping=air_damping,
                    step_guard="off", precision="f64")


@pytest.mark.slow
def test_chain_critical_step_of_symplectic_euler_is_sqrt_m_over_k():
    scene = chain_scene("explicit", 0.0)
    omega = omega_max_exact(scene.model)
    assert omega == pytest.approx(19.990, abs=5e-4)  # the number docs/algorithms.md quotes
    # bisection between 0.9 and 1.1 x sqrt(m/k): runs of 2000 steps from the highest mode, "grows" = its
    # displacement passes 1000 x the start (a bounded run near the limit peaks at ~1/sqrt(2 (1 - h w / 2)))
    h = critical_step(scene, 0.09, 0.11, rel_tol=1e-5)
    assert h == pytest.approx(math.sqrt(CHAIN_M / CHAIN_K), rel=0.01)
    exact = 2.0 / omega  # = 0.100049 s, 0.05 % above sqrt(m/k)
    assert abs(h / exact - 1) < 1e-4 < abs(h / math.sqrt(CHAIN_M / CHAIN_K) - 1)


@pytest.mark.slow
@pytest.mark.parametrize("integrator", ["explicit", "verlet", "central-difference"])
def test_chain_critical_step_with_air_drag_matches_the_closed_form(integrator):
    """gamma = 2 1/s (hw ~ 2 at h ~ 0.1 s: the drag term matters). Closed forms (docs/algorithms.md, step limits):
    symplectic Euler h^2 w^2 + 2 h gamma < 4 (4.9 % below 2/w), Verlet h w < sqrt(4 - 2 c_d) with
    c_d = 1 - exp(-gamma h) (4.5 % below), central difference 2/w whatever gamma."""
    gamma = 2.0
    scene = chain_scene(integrator, gamma)
    cls = type(scene.integrator)
    omega = omega_max_exact(scene.model)
    theory = cls.max_stable_dt(omega, gamma, 0.0)
    closed = {"explicit": (-2 * gamma + math.sqrt(4 * gamma**2 + 16 * omega**2)) / (2 * omega**2),
              "central-difference": 2.0 / omega}
    if integrator in closed:  # the bisection on is_stable agrees with the explicit root
        assert theory == pytest.approx(closed[integrator], rel=1e-9)
    else:
        h = theory
        assert h * omega == pytest.approx(math.sqrt(4 - 2 * (1 - math.exp(-gamma * h))), rel=1e-9)
    measured = critical_step(scene, 0.9 * theory, 1.1 * theory, rel_tol=1e-4)
    assert measured == pytest.approx(theory, rel=0.01)
    # and the damping moved the limit as predicted (none for central difference)
    shift = 1 - theory * omega / 2
    assert shift == pytest.approx({"explicit": 0.049, "verlet": 0.045, "central-difference": 0.0}[integrator], abs=2e-3)
