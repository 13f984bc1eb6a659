"""The placement picture: the shipped mannequin and the pieces where their placements put them, before sewing, from
the front and from the side, each piece in its colour on the page (layout.PIECE_COLOURS).

The pieces are meshed and placed as a drape would place them (taichi_cloth.garment.garment.build_garment, seams
left out so that a seam still being set up cannot stop the picture), at the garment's spacing but no finer than
VIEW_SPACING, and drawn by the stills' software renderer (taichi_cloth.still.render_views), framed on the body from
a little below the lowest piece up.
"""
from __future__ import annotations

import dataclasses
import functools
import io

import numpy as np

from ..garment.garment import build_garment
from ..still import VIEWS, render_views
from .layout import piece_colour

#: [m] the picture's pieces are meshed no finer than this (what it shows is where they are, not their mesh)
VIEW_SPACING = 0.02
#: [px] the panels' height
PANEL_PX = 480
#: [m] how far below the lowest piece the frame starts
BELOW = 0.25


@functools.lru_cache(maxsize=1)
def mannequin():
    """The shipped mannequin's Body (its frames are the placement anchors), analysed once."""
    from ..body.landmarks import Body

    return Body.from_mannequin()


def anchors() -> list[str]:
    """The anchors a placement can name, in the mannequin's order (torso, waist, hips front and back, the arms)."""
    return list(mannequin().frames)


def _rgb(hex_colour: str) -> np.ndarray:
    return np.array([int(hex_colour[i:i + 2], 16) for i in (1, 3, 5)], np.float64) / 255.0


def placement_picture(spec) -> bytes:
    """PNG bytes: the front and side views of the mannequin with the pieces of a GarmentSpec placed on it, each
    view named, the pieces' names in their colours below. PatternError (naming the piece) when a placement fails."""
    from PIL import Image, ImageDraw, ImageFont  # matplotlib's own image library: only when a picture is drawn

    body = mannequin()
    flat = dataclasses.replace(spec, seams=[], fixed=[], spacing=max(spec.spacing, VIEW_SPACING), levels=1,
                               resolution=None)
    garment = build_garment(flat, body)
    x = garment.data.positions
    owner = garment.piece_of_particle()
    colours = np.array([_rgb(piece_colour(k)) for k in range(len(spec.pieces))])
    keep = body.vertices[:, 1] >= x[:, 1].min() - BELOW
    views = [v for v in VIEWS if v[0] in ("front", "side")]
    panels = render_views(x, garment.data.triangles, colours[owner], [(body.vertices, body.triangles)], views=views,
                          panel_px=PANEL_PX, frame_on=np.vstack([body.vertices[keep], x]))
    gap, top, bottom = 12, 28, 30
    width = sum(p.rgb.shape[1] for p in panels) + gap * (len(panels) + 1)
    height = max(p.rgb.shape[0] for p in panels) + top + bottom
    image = Image.new("RGB", (width, height), (250, 250, 247))
    draw = ImageDraw.Draw(image)
    font = ImageFont.load_default(size=15)
    x0 = gap
    for p in panels:
        image.paste(Image.fromarray((255 * p.rgb).astype(np.uint8)), (x0, top))
        draw.text((x0 + p.rgb.shape[1] // 2, top // 2), p.name, fill=(40, 40, 40), font=font, anchor="mm")
        x0 += p.rgb.shape[1] + gap
    x0 = gap
    for k, piece in enumerate(spec.pieces):
        draw.rectangle((x0, height - bottom + 8, x0 + 14, height - bottom + 22), fill=piece_colour(k))
        draw.text((x0 + 20, height - bottom + 15), piece.name, fill=(40, 40, 40), font=font, anchor="lm")
        x0 += 30 + int(draw.textlength(piece.name, font=font))
    out = io.BytesIO()
    image.save(out, format="png")
    return out.getvalue()
