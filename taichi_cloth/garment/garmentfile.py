"""Garment files (TOML): our equivalent of Hsiao 2006's .gar file. One file holds the pieces, seams, fixed points,
material and placement of a garment; every length is in the file's `units`.

    name = "skirt"
    units = "cm"                  # m | cm | mm | in: every length below (outline, spacing, at, offset, height)
    material = "cotton"           # a preset, or a table: preset, density [kg/m^2], stretch [N/m], shear, bend, damping,
                                  # viscosity [m^2/s]
    spacing = 2.0                 # particle spacing along the outlines (and the interior lattice cell), or
    # resolution = "fit"          # a preset instead: "draft" (2 cm), "fit" (1 cm), "fine" (5 mm); coarse to fine
                                  # it also sets the levels (3, 5, 5: the first at 4, 4 and 2 cm)
    levels = 1                    # 4-8 levels meshed per piece (the finest, at `spacing`, is simulated)
    # dxf = "skirt.dxf"           # pieces from a DXF file: a [[pieces]] entry without `outline` takes the DXF
                                  # piece of its name (layer or block); `corners = { hem_left = 0, ... }` names
                                  # its corners
    # dxf_units = "in"            # the DXF's unit when the file gives none or a wrong one (default: its
                                  # $INSUNITS, else its "Units:" text, else mm if its pieces are of a garment's size)
    # dxf_size = "M"              # the size of a graded DXF (default: its "Sample Size:")
    # seam_allowance = 1.0        # taken off the DXF's pieces (a file of cut lines without sew lines), in `units`;
                                  # a [[pieces]] entry may give its own

    [[pieces]]
    name = "front"
    outline = [                   # corners in loop order; each says how the outline runs on to the next corner:
      { at = [-30, 0], name = "hem_left" },                  # straight (default)
      { at = [30, 0], name = "hem_right" },
      { at = [20, 60], name = "waist_right", bspline = [[0, 61.5]] },   # a B-spline through interior control points
      { at = [-20, 60], name = "waist_left" },               # (or polyline = [[u, v], ...], or bulge = b: an arc)
    ]
    placement = { anchor = "waist_front", at = [0, 60], offset = 2, wrap = true }   # also height, angle [deg]
    # placement = { origin = [0, 100, 0], u_axis = [1, 0, 0], v_axis = [0, 1, 0], at = [0, 0] }: flat, no body
    # copy = "front", mirror = true: the outline of another piece (mirrored left-right)
    # a DXF piece is turned so that its grain line runs up (rotate = 90: turned 90 degrees counter-clockwise
    # instead), and a half on a fold is unfolded into the whole piece (unfold = false: kept as the half)

    [[seams]]                     # pick each side from one corner to another: point i meets point i
    name = "left side"
    a = { piece = "front", from = "hem_left", to = "waist_left" }
    b = { piece = "back", from = "hem_right", to = "waist_right" }
    # tolerance = 0.1             # largest relative length mismatch of the two sides

    [[fixed]]                     # a particle held still: a corner (or [u, v]) of a piece, at its placed position
    piece = "front"               # or, with anchor = "waist_front", at that body point (+ offset outward)
    point = "waist_left"

Pieces are drawn as seen from outside the body, v up. Anchors (body frames) are listed in
taichi_cloth.garment.placement. Bad input gets one PatternError naming the file, the table and the key.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

from ..errors import PatternError
from ..material import Material
from ..schema import (MATERIAL_TABLE, Array, Field, Table, Validator, material_of, nonneg, nonzero, positive,
                      read_toml)
from .garment import RESOLUTIONS, FixedPoint, FreePlacement, GarmentSpec
from .garmentcode import read_specification
from .pattern import PatternPiece, unit_scale
from .placement import Placement
from .seams import DEFAULT_LENGTH_TOLERANCE, Seam, SeamSide

_SIDE = Table({"piece": Field("str"), "from": Field("corner"), "to": Field("corner")}, required=True)

GARMENT_SCHEMA = Table({
    "name": Field("str", None),
    "units": Field("str", "m", choices=("m", "cm", "mm", "in")),
    "material": MATERIAL_TABLE,
    "spacing": Field("number", None, check=positive),
    "resolution": Field("str", None, choices=tuple(RESOLUTIONS)),
    "levels": Field("int", 1, lambda v: None if 1 <= v <= 6 else "must lie in 1..6"),
    "dxf": Field("str", None),
    "dxf_units": Field("str", None, choices=("m", "cm", "mm", "in")),
    "dxf_size": Field("str", None),
    "seam_allowance": Field("number", 0.0, nonneg),
    "pieces": Array(Table({
        "name": Field("str"), "outline": Field("tables", None), "copy": Field("str", None),
        "mirror": Field("bool", False), "corners": Field("names", None), "rotate": Field("number", None),
        "unfold": Field("bool", True), "seam_allowance": Field("number", None, nonneg),
        "placement": Table({"anchor": Field("str", None), "at": Field("vec2", None),
                            "offset": Field("number", None, nonneg), "wrap": Field("bool", True),
                            "height": Field("number", 0.0), "angle": Field("number", 0.0),
                            "origin": Field("vec3", None), "u_axis": Field("vec3", [1.0, 0.0, 0.0], nonzero),
                            "v_axis": Field("vec3", [0.0, 1.0, 0.0], nonzero)}, required=True)})),
    "seams": Array(Table({"name": Field("str", None), "a": _SIDE, "b": _SIDE,
                          "tolerance": Field("number", DEFAULT_LENGTH_TOLERANCE, positive)})),
    "fixed": Array(Table({"piece": Field("str"), "point": Field("point"), "anchor": Field("str", None),
                          "offset": Field("number", None, nonneg)})),
})


def load_garment(path, material: Material | None = None) -> GarmentSpec:
    """Parse a garment file into a GarmentSpec (lengths in metres). `material` overrides the file's. A `.json` file
    is a GarmentCode specification, read as the garment file taichi_cloth.garment.garmentcode.read_specification
    makes of it (cotton at 2 cm unless `material`)."""
    path = Path(path)
    data = (read_specification(path) if path.suffix.lower() == ".json"
            else read_toml(path, str(path), "garment", PatternError))
    return garment_from_dict(data, path, material)


def garment_from_dict(data: dict, path, material: Material | None = None, dxf_reader=None) -> GarmentSpec:
    """The GarmentSpec of a garment file's parsed content `data` (what tomllib gives), checked as load_garment
    checks a file: as if it were the file at `path`, which names it in every message and whose folder a relative
    `dxf` is read from. `dxf_reader(path, units=None, size=None, as_drawn=False) -> [PatternPiece]` reads the DXF
    (default read_dxf; the pattern studio passes one that keeps what it has read, since it checks the set-up after
    every edit)."""
    path = Path(path)
    label = str(path)
    cfg = Validator(label, PatternError).table(GARMENT_SCHEMA, data, "", "")
    try:
        return _spec(cfg, path, material, dxf_reader)
    except PatternError as exc:
        raise PatternError(f"{label}: {exc}") from None


def _placement(pl: dict, s: float, where: str):
    """A Placement around a body anchor, or a FreePlacement (origin, u_axis, v_axis) laid flat in space."""
    at = None if pl["at"] is None else (s * pl["at"][0], s * pl["at"][1])
    if (pl["anchor"] is None) == (pl["origin"] is None):
        raise PatternError(f"{where}: give either anchor (a body anchor) or origin (a point in space), not "
                           f"{'both' if pl['anchor'] else 'neither'}")
    if pl["origin"] is not None:
        try:
            return FreePlacement(tuple(s * c for c in pl["origin"]), tuple(pl["u_axis"]), tuple(pl["v_axis"]),
                                 at or (0.0, 0.0))
        except PatternError as exc:  # parallel axes (a zero one is refused by the schema)
            raise PatternError(f"{where}: {str(exc).removeprefix('free placement: ')}") from None
    return Placement(anchor=pl["anchor"], at=at, **({} if pl["offset"] is None else {"offset": s * pl["offset"]}),
                     wrap=pl["wrap"], height=s * pl["height"], angle=pl["angle"])


def _spec(cfg: dict, path: Path, material: Material | None, dxf_reader=None) -> GarmentSpec:
    s = unit_scale(cfg["units"])
    if (cfg["spacing"] is None) == (cfg["resolution"] is None):
        raise PatternError("give either spacing (a length) or resolution (draft, fit or fine), not "
                           + ("both" if cfg["spacing"] is not None else "neither"))
    dxf_pieces = None
    if cfg["dxf"] is not None:
        if dxf_reader is None:
            from .dxf import read_dxf as dxf_reader  # ezdxf (0.5 s to import): only a garment drawn in a DXF file

        dxf_path = Path(cfg["dxf"])
        dxf_path = dxf_path if dxf_path.is_absolute() else path.parent / dxf_path
        dxf_pieces = {p.name: p for p in dxf_reader(dxf_path, units=cfg["dxf_units"], size=cfg["dxf_size"],
                                                    as_drawn=True)}
    else:
        for key in ("dxf_units", "dxf_size"):
            if cfg[key] is not None:
                raise PatternError(f"{key} is about the file `dxf` names: give dxf too, or leave {key} out")
        if cfg["seam_allowance"] or any(p["seam_allowance"] for p in cfg["pieces"]):
            raise PatternError("seam_allowance is taken off a DXF's cut lines: give dxf too (an outline here is "
                               "the sew line already)")
    pieces, placements = {}, {}
    for k, p in enumerate(cfg["pieces"]):
        where = f"[[pieces]] #{k + 1} ({p['name']!r})"
        given = [key for key in ("outline", "copy") if p[key] is not None]
        if len(given) > 1:
            raise PatternError(f"{where}: give either outline or copy, not both")
        if p["name"] in pieces:
            raise PatternError(f"{where}: duplicate piece name {p['name']!r}")
        if p["outline"] is not None:
            piece = PatternPiece.from_corners(p["name"], p["outline"], units=cfg["units"])
        elif p["copy"] is not None:
            if p["copy"] not in pieces:
                raise PatternError(f"{where} copy: no earlier piece named {p['copy']!r}")
            piece = pieces[p["copy"]].transformed(mirror=p["mirror"], name=p["name"])
        elif dxf_pieces is not None:
            if p["name"] not in dxf_pieces:
                raise PatternError(f"{where}: the DXF file has no piece {p['name']!r} (it has "
                                   f"{', '.join(dxf_pieces)})")
            piece = dxf_pieces[p["name"]]
            piece = piece.unfolded() if p["unfold"] and piece.fold is not None else piece
            allowance = cfg["seam_allowance"] if p["seam_allowance"] is None else p["seam_allowance"]
            piece = piece.inset(s * allowance).upright(p["rotate"])
        else:
            raise PatternError(f"{where}: needs an outline (or copy, or a dxf file at the top level)")
        if p["seam_allowance"] is not None and (p["outline"] is not None or p["copy"] is not None):
            raise PatternError(f"{where}: seam_allowance is taken off a DXF piece's cut line; an outline or a copy "
                               f"is a sew line already")
        if p["mirror"] and p["copy"] is None:
            piece = piece.transformed(mirror=True)
        if p["corners"] is not None:
            names = list(piece.corner_names)
            for name, idx in p["corners"].items():
                if not 0 <= idx < len(names):
                    raise PatternError(f"{where} corners: {name} = {idx} is not a corner index "
                                       f"(0..{len(names) - 1})")
                names[idx] = name
            piece = dataclasses.replace(piece, corner_names=names)
        piece.validate()
        pieces[piece.name] = piece
        placements[piece.name] = _placement(p["placement"], s, f"{where} placement")
    seams = [Seam(sm["name"] or f"seam {k + 1}", SeamSide(sm["a"]["piece"], sm["a"]["from"], sm["a"]["to"]),
                  SeamSide(sm["b"]["piece"], sm["b"]["from"], sm["b"]["to"]), sm["tolerance"])
             for k, sm in enumerate(cfg["seams"])]
    fixed = [FixedPoint(f["piece"], f["point"] if not isinstance(f["point"], list) else
                        (s * f["point"][0], s * f["point"][1]), f["anchor"],
                        **({} if f["offset"] is None else {"offset": s * f["offset"]})) for f in cfg["fixed"]]
    mat = material if material is not None else material_of(cfg.get("material"))
    spec = GarmentSpec(cfg["name"], list(pieces.values()), seams, placements, fixed, mat,
                       s * (cfg["spacing"] or 1.0), cfg["levels"])
    if cfg["resolution"] is not None:
        spec.at_resolution(cfg["resolution"])
    spec.validate()
    return spec
