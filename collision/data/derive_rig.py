"""Derive collision/data/mannequin_joints.json from the CC0 MakeHuman base mesh: the mannequin's joint centres.

    python collision/data/derive_rig.py /path/to/makehuman [--out collision/data/mannequin_joints.json]

MakeHuman's hm08 `base.obj` carries a small cube of helper geometry at every joint of its default skeleton (groups
`joint-pelvis`, `joint-spine-1` ... `joint-l-shoulder`, `joint-l-elbow`, ...); MakeHuman places its rig's joints at
those cubes' centres. This script writes the centre of every such group (the mean of its vertices) in the
mannequin's frame: decimetres x 0.1 to metres, then the translation stored in mannequin.npz (soles on y = 0). The
helper cubes themselves are not part of the mannequin (derive_mannequin.py keeps the body group only). Licence:
CC0 1.0, as the mesh (MANNEQUIN.md).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def joint_centres(obj: Path) -> dict[str, list[float]]:
    """name (without "joint-") -> centre [dm] of every joint helper group of base.obj."""
    vertices, groups, group = [], {}, None
    for line in obj.read_text(encoding="utf-8", errors="replace").splitlines():
        if line.startswith("v "):
            vertices.append([float(x) for x in line.split()[1:4]])
        elif line.startswith("g "):
            group = line.split(maxsplit=1)[1].strip()
        elif line.startswith("f ") and group and group.startswith("joint-"):
            groups.setdefault(group[len("joint-"):], set()).update(int(w.split("/")[0]) - 1 for w in line.split()[1:])
    v = np.asarray(vertices)
    return {name: v[sorted(idx)].mean(0).tolist() for name, idx in sorted(groups.items())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("source", type=Path, help="folder with base.obj")
    ap.add_argument("--out", type=Path, default=HERE / "mannequin_joints.json")
    args = ap.parse_args()
    with np.load(HERE / "mannequin.npz") as z:
        translation = z["translation"].astype(np.float64)
    joints = {name: [round(float(c), 5) for c in np.asarray(p) * 0.1 + translation]
              for name, p in joint_centres(args.source / "base.obj").items()}
    args.out.write_text(json.dumps({"units": "m, the mannequin's frame (Y up, soles on y = 0)",
                                    "source": "MakeHuman hm08 base.obj joint helper groups, CC0 1.0",
                                    "joints": joints}, indent=1) + "\n")
    print(f"{len(joints)} joints -> {args.out}")


if __name__ == "__main__":
    main()
