"""Wind: a per-particle aerodynamic force along the surface normal (docs/algorithms.md, sewing, our common form):

    f_i = c_w * ((v_wind - v_i) . n_i) * n_i * A_i

with n_i the unit vertex normal and A_i the vertex's share of the deformed area. Built only when a
scene names wind; its normal kernel is then compiled, otherwise never.
"""
from __future__ import annotations

import math

import numpy as np
import taichi as ti

from clothbase.fields import FieldBlock

from .normals import VertexNormals


@ti.data_oriented
class Wind:
    """velocity [m/s] (3-vector), coefficient c_w [kg/(m^2*s)] = [N*s/m^3], gust: relative amplitude of a
    sinusoidal modulation of the wind speed, gust_frequency [Hz]."""

    def __init__(self, model, state, velocity=(5.0, 0.0, 0.0), coefficient: float = 1.0,
                 gust: float = 0.0, gust_frequency: float = 0.5):
        if coefficient < 0:
            raise ValueError(f"wind coefficient must be >= 0, got {coefficient}")
        if len(model.data.triangles) == 0:
            raise ValueError("wind needs a cloth with triangles (it acts along the surface normal)")
        self.model = model
        self.base_velocity = np.asarray(velocity, dtype=np.float64).reshape(3)
        self.gust, self.gust_frequency = float(gust), float(gust_frequency)
        self.normals = VertexNormals(model, state)
        blk = FieldBlock()
        self.velocity = blk.vector(3, model.fp, ())
        self.coefficient = blk.scalar(model.fp, ())
        blk.finalize(self)
        self.coefficient[None] = float(coefficient)
        self.prepare_velocity(0.0)

    def velocity_at(self, t: float) -> np.ndarray:
        """Wind velocity [m/s] at time t [s]."""
        return self.base_velocity * (1.0 + self.gust * math.sin(2.0 * math.pi * self.gust_frequency * t))

    def prepare_velocity(self, t: float) -> None:
        self.velocity[None] = self.velocity_at(t).tolist()

    def prepare(self, t: float) -> None:
        """Update the gusting velocity and the normals for a force evaluation at time t [s]."""
        if self.gust:
            self.prepare_velocity(t)
        self.normals.compute(False)

    @ti.func
    def force(self, i, xi, vi):
        n = self.normals.normal[i]
        area = n.norm()
        f = ti.Vector.zero(self.model.fp, 3)
        if area > 0:
            f = self.coefficient[None] * (self.velocity[None] - vi).dot(n / area) * n
        return f
