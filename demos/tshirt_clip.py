"""The T-shirt on a body that moves (demos/scenes/tshirt_clip.toml): the shirt is sewn on the mannequin, then the
mannequin brings its arms down from the A-pose and twists its torso 30 degrees each way, and the shirt follows.

    python demos/tshirt_clip.py [--out DIR] [--frames N] [--png] [...the options of `python -m taichi_cloth run`]

First writes the mannequin's clip (linear-blend skinning of its default skeleton, taichi_cloth.body.clip) as a mesh
sequence, DIR/mannequin_clip.npz, exactly as a body-model pipeline would hand one over; the scene's body collider
reads it (`sequence`), so the run exercises the path a user's own animated body takes. Writes DIR/tshirt_clip.rrd
(body and garment moving together) and the final mesh; prints the run summary and the quality table.
"""
import tomllib

from _common import SCENES, arguments, ends
from clothbase.sequences import save_mesh_sequence
from taichi_cloth.body.clip import mannequin_clip
from taichi_cloth.cli import run_scene_file


def main(argv=None) -> int:
    args = arguments(__doc__, argv)
    args.out.mkdir(parents=True, exist_ok=True)
    clip = save_mesh_sequence(args.out / "mannequin_clip.npz", mannequin_clip())
    print(f"wrote the mannequin's clip: {clip}")
    scene = tomllib.loads((SCENES / "tshirt_clip.toml").read_text(encoding="utf-8"))
    scene["colliders"][0]["sequence"] = str(clip.resolve())
    run_scene_file(scene, args, base_dir=SCENES)
    return 0


if __name__ == "__main__":
    raise SystemExit(ends(main))
