"""Quality presets: preview, balanced and accurate, derived from the measured speed/accuracy front.

`python -m taichi_cloth bench tradeoff --write-presets` measures every integrator, step and 4-8 level against
the implicit reference on the standard scenes and writes the cheapest configuration under each preset's error
target into taichi_cloth/data/quality_presets.toml (shipped). A preset names:
  integrator, options     the integrator and its options (CG tolerance, sweeps ...)
  dt                      the step [s], or dt_bound_fraction: that fraction of an explicit integrator's
                          linear-theory stable step on the scene's cloth (docs/algorithms.md, step limits)
  level                   4-8 levels relative to the finest the scene names: 0 keeps the cloth, -1 and -2
                          coarsen it by sqrt(2) and 2 in spacing ([multilevel] levels, or [cloth.grid]
                          resolution); a mesh or garment cloth keeps its mesh
A scene file takes `quality = "balanced"` at the top level, the CLI `run --quality balanced`; `--integrator` and
`--dt` still override what the preset picks.
"""
from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from .errors import SceneError

PRESETS_PATH = Path(__file__).parent / "data" / "quality_presets.toml"
QUALITIES = ("preview", "balanced", "accurate")


@dataclass(frozen=True)
class Preset:
    """One quality preset (see the module docstring); `measured` holds what the study measured for it."""

    name: str
    integrator: str
    level: int = 0
    dt: float | None = None
    dt_bound_fraction: float | None = None
    options: dict = field(default_factory=dict)
    measured: dict = field(default_factory=dict)

    def describe(self) -> str:
        step = f"dt = {self.dt:.4g} s" if self.dt is not None else f"dt = {self.dt_bound_fraction:g} x the stable step"
        opts = "".join(f", {k} = {v}" for k, v in self.options.items())
        return f"quality {self.name!r}: {self.integrator}{opts}, {step}, level {self.level:+d}"


def load_presets(path: Path = PRESETS_PATH) -> dict[str, Preset]:
    """The presets in `path` (default: the shipped ones), by name."""
    data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    out = {}
    for name in QUALITIES:
        t = data.get(name)
        if t is None:
            raise SceneError(f"{path}: no [{name}] preset")
        if ("dt" in t) == ("dt_bound_fraction" in t):
            raise SceneError(f"{path}: [{name}] needs exactly one of dt and dt_bound_fraction")
        out[name] = Preset(name, t["integrator"], int(t.get("level", 0)), t.get("dt"), t.get("dt_bound_fraction"),
                           dict(t.get("options", {})), dict(t.get("measured", {})))
    return out


def preset(name: str, path: Path = PRESETS_PATH) -> Preset:
    """The preset called `name` (preview, balanced or accurate)."""
    if name not in QUALITIES:
        raise SceneError(f"quality must be one of {', '.join(QUALITIES)}, got {name!r}")
    return load_presets(path)[name]


def coarsen_resolution(resolution, level: int) -> list[int]:
    """A grid resolution (particles per side) with its spacing grown by sqrt(2)^-level (level <= 0): the
    4-8 level step on a square grid, rounded to whole particles, at least 2 per side."""
    scale = 2.0 ** (level / 2.0)
    return [max(2, round((r - 1) * scale) + 1) for r in resolution]
