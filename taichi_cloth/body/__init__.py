"""Body morphing to measured girths (Zhang et al. 2017, sections 1 and 3.1): blend shapes of a base body, girths measured
like a tape on plane sections, and a fit of the blend-shape weights to target girths. Numpy and scipy; metres.

    from taichi_cloth.body import fit_body
    fit = fit_body({"chest": 0.96, "waist": 0.80, "hips": 1.00})   # the shipped mannequin
    print(fit.format())                                             # fit.vertices (V,3), fit.triangles (T,3)

Modules: section (plane slices of a mesh, convex hulls), landmarks (Body: the parts, frames, landmark heights
and girths of a body mesh, what garment placement and the girth gauge start from), blendshapes (BlendShapes: base
+ channels of larger/smaller limit shapes), girth (periodic_spline_length, tape_girth, GirthGauge), fit (fit_body,
girth_ranges, BodyFit), cli (the `body` subcommand; not imported here). Nothing here imports taichi_cloth.garment.
"""
import importlib

# Lazy exports (PEP 562): garment placement imports .landmarks from here, so this file stays light (no scipy) and
# loads a submodule on the first use of one of its names.
_EXPORTS = {
    "section": ("Loop", "MeshSlicer", "convex_hull", "hull_perimeter", "loop_girth", "plane_basis"),
    "landmarks": ("Body", "BodyFrame"),
    "blendshapes": ("BlendShapes", "Channel", "Shape", "read_mesh"),
    "girth": ("GIRTHS", "GirthDefinition", "GirthGauge", "periodic_spline_length", "tape_girth"),
    "fit": ("BodyFit", "GirthOutOfRange", "default_body", "fit_body", "girth_ranges"),
}
_WHERE = {name: module for module, names in _EXPORTS.items() for name in names}

__all__ = sorted(_WHERE)


def __getattr__(name):
    if name in _WHERE:
        value = getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
        globals()[name] = value   # later look-ups skip this function
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_WHERE))
