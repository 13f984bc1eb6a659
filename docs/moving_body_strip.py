"""Draws docs/moving-body.png: front views of the 2 cm T-shirt on the mannequin's clip (demos/scenes/tshirt_clip.toml)
at five moments, body and garment as the still pictures draw them.

    .venv/bin/python docs/moving_body_strip.py [PNG]     (about a minute; default out/moving-body.png)
"""
import argparse
import sys
import tomllib
from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from clothbase.sequences import save_mesh_sequence  # noqa: E402
from taichi_cloth.body.clip import mannequin_clip  # noqa: E402
from taichi_cloth.cli import add_run_arguments  # noqa: E402
from taichi_cloth.run import load_scene_file  # noqa: E402
from taichi_cloth.still import render_views  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
out = Path("out")
out.mkdir(exist_ok=True)
clip = save_mesh_sequence(out / "clip.npz", mannequin_clip())
cfg = tomllib.loads((ROOT / "demos" / "scenes" / "tshirt_clip.toml").read_text())
cfg["colliders"][0]["sequence"] = str(clip.resolve())
p = argparse.ArgumentParser()
add_run_arguments(p)
sc = load_scene_file(cfg, p.parse_args(["--out", str(out), "--no-progress"]), ROOT / "demos" / "scenes").scene
times = [0.75, 1.75, 2.25, 3.25, 4.0]
body = sc.controller("colliders").bodies[0]
fig, axes = plt.subplots(1, len(times), figsize=(3.2 * len(times), 5.2))
for ax, t in zip(axes, times):
    frames = int(round((t - sc.state.t) * cfg["fps"]))
    if frames > 0:
        sc.run(frames, progress=False, until_rest=False)
    x, tri = sc.positions(), sc.model.data.triangles
    rgb = np.tile([0.85, 0.45, 0.35], (len(x), 1))
    panels = render_views(x, tri, rgb, bodies=[(body.vertices_np, body.triangles_np)],
                          frame_on=body.vertices_np[body.vertices_np[:, 1] > 0.8])
    ax.imshow(panels[0].rgb)
    ax.axis("off")
    ax.set_title(f"t = {sc.state.t:.2f} s (clip {max(0.0, body.t_pose):.2f} s)", fontsize=10)
fig.suptitle("The 2 cm T-shirt on the mannequin's clip: arms down (0-1 s), twist +30, -30, 0 degrees (1-3 s)")
plt.tight_layout()
target = sys.argv[1] if len(sys.argv) > 1 else out / "moving-body.png"
fig.savefig(target, dpi=80)
print(f"wrote {target}")
