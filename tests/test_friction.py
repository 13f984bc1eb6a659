"""Coulomb friction in the implicit step (taichi_cloth.integrators.implicit, _contact_friction): a sheet lying on a
slope of angle theta sticks where tan(theta) <= mu and slides with the acceleration g (sin(theta) - mu cos(theta))
where it is steeper; a skirt on a loose waistband that crept down the body in stick-slip bursts comes to rest."""
import math

import numpy as np
import pytest

import taichi_cloth as tc

MU, G, H = 0.5, 9.81, 1 / 120


def sheet_on_a_slope(theta: float, mu: float = MU) -> tc.Scene:
    """A 6 cm cotton sheet (6 x 6 particles) lying on a plane tilted by theta [rad] about z, at the collider's
    thickness (3 mm), no air drag: downhill is (-cos theta, -sin theta, 0)."""
    normal = np.array([-math.sin(theta), math.cos(theta), 0.0])
    cloth = tc.ClothBuilder.grid((0.06, 0.06), (6, 6), "cotton", plane="xz")
    turn = np.array([[math.cos(theta), -math.sin(theta), 0.0], [math.sin(theta), math.cos(theta), 0.0], [0, 0, 1]])
    cloth.positions[:] = cloth.positions @ turn.T + 0.003 * normal
    plane = {"type": "plane", "point": [0.0, 0.0, 0.0], "normal": normal.tolist(), "friction": mu, "thickness": 0.003}
    return tc.Scene(cloth, dt=H, air_damping=0.0, integrator="implicit", colliders=[plane])


def slide(theta_deg: float, mu: float = MU, steps: int = 60) -> tuple[float, float]:
    """(distance [m] the sheet's centre moved downhill, its mean downhill velocity [m/s]) after `steps` steps."""
    theta = math.radians(theta_deg)
    sc = sheet_on_a_slope(theta, mu)
    downhill = np.array([-math.cos(theta), -math.sin(theta), 0.0])
    start = sc.positions().mean(axis=0)
    sc.run(steps // 2, progress=False)  # 60 fps, two steps a frame
    return float((sc.positions().mean(axis=0) - start) @ downhill), float(sc.velocities().mean(axis=0) @ downhill)


@pytest.mark.parametrize("theta", [10.0, 20.0, 26.0])
def test_a_sheet_sticks_on_a_slope_within_the_friction_cone(theta):
    assert math.tan(math.radians(theta)) < MU
    moved, velocity = slide(theta)
    # in half a second it would slide 0.2-0.55 m without friction; it moves only in the first step, before the plane
    # reports a contact (a free fall of h^2 g: 0.7 mm at most, 0.1-0.3 mm along the slope)
    assert abs(moved) < 5e-4 and abs(velocity) < 1e-3


@pytest.mark.parametrize("theta", [30.0, 40.0, 60.0])
def test_a_sheet_slides_down_a_steeper_slope_with_the_coulomb_acceleration(theta):
    """The friction force, from the velocity after half a second: m (g sin(theta) - a) = mu m g cos(theta) within 1 %
    (Coulomb: a = g (sin(theta) - mu cos(theta)); without friction the sheet is 2-4 times as fast)."""
    t = math.radians(theta)
    _, velocity = slide(theta)
    friction = G * math.sin(t) - velocity / 0.5  # per unit mass [N/kg]
    assert friction == pytest.approx(MU * G * math.cos(t), rel=0.01)
    _, slick = slide(theta, mu=0.0)
    assert slick == pytest.approx(G * math.sin(t) * 0.5, rel=1e-3)
