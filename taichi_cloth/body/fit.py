"""Fit a body to measured girths: the blend-shape weights at which each named girth equals its target (Zhang et al. 2017,
section 3.1.2).

Zhang et al. 2017 step one channel's weight from 0 by a fixed increment until the girth is within a preset error of
the user's value. Here each girth is a function of its own channel's weight, g(w) on [-1, 1] (monotone on the
mannequin), and scipy.optimize.brentq finds the root of g(w) - target in a few evaluations of the gauge (a few
ms each). The channels of the MakeHuman targets overlap (BlendShapes.overlaps) and are not local: on the
mannequin the bust target widens the whole ribcage, so per unit weight (positive side, cm) the chest channel
moves the underbust girth 16.3 (the underbust channel itself: 14.0), the underbust channel moves the chest
12.1 and the waist 10.4 (the waist channel: 9.0), the hips channel the thigh 3.1; chest, waist, hips, neck,
upper arm and thigh are nearly independent. The asked girths are therefore solved together by Gauss-Seidel
sweeps: each sweep solves every asked girth's channel in turn (brentq on its bounds) with the others' current
weights fixed, and the sweeps stop when every girth is within `tolerance` of its target. Where channels are
strongly coupled the sweeps converge linearly (x0.6-0.8 per sweep for chest + underbust), so from the third
sweep on Aitken's delta-squared extrapolation of the weights is tried and kept if it brings the girths closer
(chest + underbust + waist + hips: 15 plain sweeps, 6 with it). At most `max_sweeps` sweeps, else BodyError
naming the girths still off and the channels stuck at a limit: each girth may be in range alone while the
combination is not (chest 0.90 m with underbust 0.78 m: the chest channel's growth of the underbust exceeds
what the underbust channel can take back).

Inputs and outputs in metres: targets {girth: m}; BodyFit.vertices (V,3) float64 [m], triangles (T,3) int64,
weights {channel: w in [-1, 1]}, girths {girth: measured m}. A girth's channel is the blend-shape channel of
the same name (chest, underbust, waist, hips, neck, upper_arm, thigh on the mannequin). Reachable range of a
girth: its value at its channel's weights -1 and +1 with every other channel at 0 (`girth_ranges`); a target
outside it raises GirthOutOfRange (a BodyError) stating the range.
"""
import functools
import math
from dataclasses import dataclass

import numpy as np

from ..errors import BodyError
from .blendshapes import BlendShapes
from .girth import GirthGauge

__all__ = ["BodyFit", "GirthOutOfRange", "default_body", "fit_body", "girth_ranges"]

MAX_SWEEPS = 10
_XTOL = 1e-9   # brentq's tolerance on a weight: a girth moves at most ~0.4 m per unit weight, i.e. < 1e-9 m


class GirthOutOfRange(BodyError):
    """A target girth its channel cannot reach. Attributes: name, target, lo, hi [m]; the message states them in
    `unit` ("m", or "cm" for the command line)."""

    def __init__(self, name: str, target: float, lo: float, hi: float, unit: str = "m"):
        if unit == "cm":
            text = f"{100 * target:g} cm is outside the reachable range {100 * lo:.1f}-{100 * hi:.1f} cm"
        else:
            text = f"{target:.3f} m is outside the reachable range {lo:.3f}-{hi:.3f} m"
        super().__init__(f"{name} {text} of this body's {name} channel")
        self.name, self.target, self.lo, self.hi = name, target, lo, hi


@functools.lru_cache(maxsize=1)
def default_body():
    """(BlendShapes, GirthGauge) of the shipped mannequin, built once per process (the gauge's body analysis
    takes about 0.5-1 s). Treat both as read-only."""
    blend = BlendShapes.from_mannequin()
    return blend, GirthGauge.from_blendshapes(blend)


def _resolve(blend, gauge):
    if blend is None:
        default_blend, default_gauge = default_body()
        return default_blend, default_gauge if gauge is None else gauge
    if gauge is None:
        gauge = GirthGauge.from_blendshapes(blend)
    if gauge.base.shape != blend.base.shape:
        raise BodyError(f"the girth gauge's body has {len(gauge.base)} vertices, the blend shapes' "
                        f"{len(blend.base)}: build the gauge on the blend shapes' base")
    return blend, gauge


def _fittable(blend: BlendShapes, gauge: GirthGauge) -> list:
    return [n for n in gauge.names if n in blend.channels]


def girth_ranges(blend: BlendShapes | None = None, gauge: GirthGauge | None = None, names=None) -> dict:
    """{girth: (lo, hi) [m]}: each girth at its channel's weight bounds (-1 and +1; 0 on a side without a
    limit) with every other channel at 0, for `names` (default: every girth that has a channel of its name).
    Defaults: the mannequin."""
    blend, gauge = _resolve(blend, gauge)
    names = _check_names(blend, gauge, _fittable(blend, gauge) if names is None else list(names))
    out = {}
    for n in names:
        g = [gauge.measure(blend.morph({n: w}), [n])[n] for w in blend.channels[n].bounds]
        out[n] = (min(g), max(g))
    return out


def _check_names(blend, gauge, names) -> list:
    valid = _fittable(blend, gauge)
    for n in names:
        if n not in valid:
            raise BodyError(f"unknown girth {n!r}; valid girths: {', '.join(valid)}")
    return names


@dataclass(eq=False)
class BodyFit:
    """The fitted body: vertices (V,3) float64 [m], triangles (T,3) int64, weights {channel: w}, girths
    {girth: measured m}, targets {girth: m}, sweeps (Gauss-Seidel sweeps done), tolerance [m]."""

    vertices: np.ndarray
    triangles: np.ndarray
    weights: dict
    girths: dict
    targets: dict
    sweeps: int
    tolerance: float = 1e-3
    evaluations: int = 0        # girth measurements made (one plane section each, or all asked girths at once)
    extrapolations: int = 0     # Aitken extrapolations kept

    def errors(self) -> dict:
        """{girth: measured - target [m]}."""
        return {n: self.girths[n] - t for n, t in self.targets.items()}

    def format(self) -> str:
        """A small table: girth, target [cm], measured [cm], error [mm], weight; and the sweeps."""
        rows = [f"{'girth':<10} {'target cm':>9} {'measured cm':>11} {'error mm':>8} {'weight':>8}"]
        for n, t in self.targets.items():
            g = self.girths[n]
            rows.append(f"{n:<10} {100 * t:9.2f} {100 * g:11.2f} {1000 * (g - t):8.2f} {self.weights[n]:+8.4f}")
        extra = f" ({self.extrapolations} extrapolated)" if self.extrapolations else ""
        rows.append(f"{self.sweeps} Gauss-Seidel sweep{'s' if self.sweeps != 1 else ''}{extra}, "
                    f"{self.evaluations} girth evaluations, tolerance {1000 * self.tolerance:g} mm")
        return "\n".join(rows)


def fit_body(targets: dict, blend: BlendShapes | None = None, gauge: GirthGauge | None = None,
             tolerance: float = 1e-3, max_sweeps: int = MAX_SWEEPS) -> BodyFit:
    """Morph `blend` (default: the mannequin) so each girth in `targets` {name: m} measures (with `gauge`,
    default GirthGauge.from_blendshapes(blend)) within `tolerance` [m] of its target (module docstring).

    Raises BodyError for an unknown girth (listing the valid ones), a non-positive or non-finite target or
    tolerance, GirthOutOfRange for a target outside its channel's reachable range, and BodyError naming the
    girths still off if max_sweeps sweeps do not converge."""
    from scipy.optimize import brentq  # 0.4 s to import: only when fitting

    blend, gauge = _resolve(blend, gauge)
    if not isinstance(targets, dict) or not targets:
        raise BodyError(f"targets must be a non-empty dict {{girth: m}}; valid girths: "
                        f"{', '.join(_fittable(blend, gauge))}")
    _check_names(blend, gauge, list(targets))
    goal = {}
    for n in [g for g in gauge.names if g in targets]:   # the gauge's order: top to bottom, a stable sweep
        try:
            x = float(targets[n])
        except (TypeError, ValueError):
            raise BodyError(f"target {n} must be a number in m, got {targets[n]!r}") from None
        if not math.isfinite(x) or x <= 0:
            raise BodyError(f"target {n} must be a positive girth in m, got {targets[n]!r}")
        goal[n] = x
    try:
        tolerance = float(tolerance)
    except (TypeError, ValueError):
        raise BodyError(f"tolerance must be a number in m, got {tolerance!r}") from None
    if not math.isfinite(tolerance) or tolerance <= 0:
        raise BodyError(f"tolerance must be a positive length in m, got {tolerance!r}")
    if int(max_sweeps) < 1:
        raise BodyError(f"max_sweeps must be at least 1, got {max_sweeps!r}")
    for n, (lo, hi) in girth_ranges(blend, gauge, list(goal)).items():
        if not lo <= goal[n] <= hi:
            raise GirthOutOfRange(n, goal[n], lo, hi)

    weights = {n: 0.0 for n in goal}
    names = list(goal)
    lo_w = np.array([blend.channels[n].bounds[0] for n in names])
    hi_w = np.array([blend.channels[n].bounds[1] for n in names])
    counter = {"evaluations": 0, "extrapolations": 0}

    def measure(w: dict) -> tuple:
        vertices = blend.morph(w)
        girths = gauge.measure(vertices, names)
        counter["evaluations"] += 1
        return vertices, girths, max(abs(girths[n] - goal[n]) for n in names)

    def done(sweep, vertices, girths):
        return BodyFit(vertices, blend.triangles.copy(), dict(weights), girths, goal, sweep, tolerance,
                       counter["evaluations"], counter["extrapolations"])

    history = []
    for sweep in range(1, int(max_sweeps) + 1):
        before = dict(weights)
        for n in names:
            fixed = blend.morph({k: w for k, w in weights.items() if k != n})

            def miss(w, n=n, fixed=fixed):
                counter["evaluations"] += 1
                return gauge.measure(blend.add_channel(fixed.copy(), n, w), [n])[n] - goal[n]

            lo, hi = blend.channels[n].bounds
            f_lo, f_hi = miss(lo), miss(hi)
            if f_lo * f_hi <= 0:
                weights[n] = float(brentq(miss, lo, hi, xtol=_XTOL))
            else:
                # the other channels pushed the target out of this one's reach for now: go as close as it can
                weights[n] = lo if abs(f_lo) < abs(f_hi) else hi
        vertices, girths, worst = measure(weights)
        if worst <= tolerance:
            return done(sweep, vertices, girths)
        if max(abs(weights[n] - before[n]) for n in names) < _XTOL:
            break   # a fixed point off target: more sweeps would repeat this one
        # Strongly coupled channels (chest and underbust move each other's girths almost as much as their own)
        # make the sweeps converge linearly, about x0.6-0.8 per sweep; the weights then follow a geometric
        # sequence whose limit Aitken's delta-squared extrapolation predicts from three sweeps. Kept only if it
        # brings the girths closer; the sweeps continue from it.
        history = history[-2:] + [np.array([weights[n] for n in names])]
        if len(history) == 3:
            x0, x1, x2 = history
            d1, d2 = x1 - x0, x2 - x1
            den = d2 - d1
            ok = np.abs(den) > 1e-12
            guess = np.clip(np.where(ok, x2 - d2 * d2 / np.where(ok, den, 1.0), x2), lo_w, hi_w)
            trial = {n: float(x) for n, x in zip(names, guess)}
            t_vertices, t_girths, t_worst = measure(trial)
            if t_worst < worst:
                counter["extrapolations"] += 1
                weights, girths, history = trial, t_girths, []
                if t_worst <= tolerance:
                    return done(sweep, t_vertices, t_girths)
    off = ", ".join(f"{n} {1000 * (girths[n] - goal[n]):+.1f} mm" for n in goal if abs(girths[n] - goal[n]) > tolerance)
    stuck = [f"{n} {weights[n]:+g}" for n in goal if weights[n] in blend.channels[n].bounds and weights[n] != 0]
    why = (f"; channels at their limits: {', '.join(stuck)} (the channels overlap, so one moves the others' girths:"
           " this combination of girths is out of this body's reach)" if stuck else "")
    raise BodyError(f"the girths {', '.join(goal)} cannot all be fitted within {1000 * tolerance:g} mm in {sweep} "
                    f"sweep{'s' if sweep != 1 else ''}: {off} off{why}")
