"""Whether the stretch limit and the colliders both hold at the end of a run, in words: the run summary's line.
The colliders run after the limit and have the last word, so where both cannot hold the limit loses."""
from __future__ import annotations

import numpy as np

from collision.self_collision import SelfCollision


def limit_and_colliders(data, x: np.ndarray, limit, colliders) -> str | None:
    """data: the model's ClothData; x: (P,3) float64 positions [m]; limit: the StretchLimit controller; colliders:
    the Colliders. Every limited spring within max_strain + tolerance, and no particle inside a collider (signed
    distance < 0); or which one lost, and by how much. None when no spring is limited."""
    limited = np.isin(data.kind, [int(k) for k in limit.kinds])
    if not limited.any():
        return None
    a, b = data.springs[limited, 0], data.springs[limited, 1]
    strain = np.linalg.norm(x[b] - x[a], axis=1) / data.rest_length[limited] - 1.0
    allowed = limit.max_strain + limit.tolerance
    over = int(np.count_nonzero(strain > allowed))
    depth = [c.signed_distance(x) for c in colliders.objects
             if hasattr(c, "signed_distance") and not isinstance(c, SelfCollision)]
    gap = np.min(depth, axis=0) if depth else np.full(len(x), np.inf)
    inside = int(np.count_nonzero(gap < 0))
    strain_text = f"max strain {100 * strain.max():.2f} % (limit {100 * allowed:.2f} %)"
    if not over and not inside:
        return f"stretch limit and colliders agree: {strain_text}, no particle inside a collider"
    lost = []
    if over:
        lost.append(f"{over} springs over the stretch limit, {strain_text}")
    if inside:
        lost.append(f"{inside} particles inside a collider, the deepest {1e3 * -gap.min():.2f} mm")
    return "stretch limit and colliders disagree: " + "; ".join(lost)
