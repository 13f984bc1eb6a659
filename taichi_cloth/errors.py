"""Errors the engine raises on purpose. Each carries one message meant for a user, never a traceback."""


class TaichiClothError(Exception):
    """Base class of every error the engine raises for bad input or a failed run."""


class SceneError(TaichiClothError, ValueError):
    """A scene (file or dict) is malformed: the message names the file, the table and the key."""


class PatternError(TaichiClothError, ValueError):
    """A pattern piece, garment file or DXF file is malformed: the message names the piece, seam or file."""


class BodyError(TaichiClothError, ValueError):
    """A body morph or measurement cannot be done: unknown channel or girth, weight out of range, limit shapes
    of another topology, a target girth out of reach: the message names the channel, girth or file."""


# A mesh is unusable (missing, empty, non-manifold, NaN vertices, degenerate faces): the message names the file.
# EngineWarning: what a user should know, printed once as one line. Both are defined in the base layer (clothbase),
# which every package imports, so that collision and multilevel raise and warn alike without importing taichi_cloth.
from clothbase.errors import EngineWarning, MeshError  # noqa: E402

__all__ = ["BlowUpError", "BodyError", "EngineWarning", "MeshError", "PatternError", "SceneError", "TaichiClothError"]


class BlowUpError(TaichiClothError, RuntimeError):
    """A run went unstable (NaN, runaway speed or strain) and was stopped.

    Attributes: integrator (name), step (index of the step that was checked), dt (s),
    suggested_dt (s, or None), reason (what was seen).
    """

    def __init__(self, message: str, *, integrator: str, step: int, dt: float, suggested_dt, reason: str):
        super().__init__(message)
        self.integrator = integrator
        self.step = step
        self.dt = dt
        self.suggested_dt = suggested_dt
        self.reason = reason
