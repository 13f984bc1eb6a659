"""When a run counts as blown up, and the BlowUpError that says so: the integrator, the step, what went wrong
and a step that would be stable (docs/integrators.md)."""
from __future__ import annotations

from .diagnostics import Measurement
from .errors import BlowUpError


def blowup_reason(m: Measurement, max_speed: float, max_strain: float) -> str | None:
    """Why the measured state counts as blown up (NaNs, speed over max_speed [m/s], strain over max_strain), or
    None when it is sane."""
    if m.nonfinite:
        return f"{m.nonfinite} particles have NaN or infinite coordinates"
    if m.max_speed > max_speed:
        return f"max speed {m.max_speed:.3g} m/s exceeds {max_speed:.3g} m/s"
    if m.max_strain > max_strain:
        return f"max strain {m.max_strain:.3g} exceeds {max_strain:.3g}"
    return None


def blowup_error(reason: str, integrator, model, air_damping: float, t: float, dt: float, steps: int,
                 bound: float | None) -> BlowUpError:
    """The error of a run that blew up by step `steps` at time t [s] with step dt [s]: the integrator's name, the
    cloth's stiffest spring and lightest particle, and a suggested step: 0.9 x `bound` (the linear-theory stable
    step [s], None for an unconditionally stable integrator) or else a quarter of dt."""
    name = integrator.name
    if bound is not None:
        suggested = 0.9 * bound
        advice = f"suggested stable step dt <= {suggested:.3g} s (linear theory, see docs/integrators.md)"
    else:
        suggested = dt / 4
        advice = f"suggested: dt = {suggested:.3g} s or more damping"
    extra = integrator.unstable_advice()
    if extra:
        advice += f"; {extra}"
    d = model.data
    k_max = float(d.stiffness.max()) if d.n_springs else 0.0
    msg = (f"blow-up: integrator {name!r} went unstable by step {steps} (t = {t:.4g} s, dt = {dt:.3g} s): {reason}. "
           f"Parameters: k_max = {k_max:.3g} N/m, m_min = {float(d.mass.min()):.3g} kg, "
           f"air_damping = {air_damping:.3g} 1/s; {advice}")
    return BlowUpError(msg, integrator=name, step=steps, dt=dt, suggested_dt=suggested, reason=reason)
