"""Scene files: a good file builds exactly what it names; every kind of mistake gets one clear line."""
import textwrap

import pytest

import taichi_cloth as tc
from taichi_cloth.cli import main
from taichi_cloth.scenefile import parse_scene

GOOD = """
name = "t"
frames = 3
[cloth]
material = "silk"
[cloth.grid]
size = [0.5, 0.5]
resolution = [6, 6]
center = [0.0, 1.0, 0.0]
[integrator]
name = "approx-implicit"
dt = 0.005
[[pins]]
near = [[-0.25, 1.25, 0.0], [0.25, 1.25, 0.0]]
"""


def write(tmp_path, text, name="scene.toml"):
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


def test_good_file_builds_what_it_names(tmp_path):
    loaded = tc.load_scene(write(tmp_path, GOOD))
    sc = loaded.scene
    assert loaded.frames == 3 and loaded.name == "t"
    assert sc.integrator.name == "approx-implicit" and sc.dt == 0.005
    assert sc.model.data.n_particles == 36 and sc.model.pinned.sum() == 2
    assert sc.model.data.mass.sum() == pytest.approx(tc.MATERIALS["silk"].density * 0.25)
    assert [c.name for c in sc.controllers] == ["pins"] and not sc.controller("pins").moving
    assert sc.forces.sources == () and sc.contacts is None


def test_self_collision_settings_from_a_table(tmp_path):
    """`[self_collision]` turns it on with its settings; a misspelled key is named with the right one."""
    sc = tc.load_scene(write(tmp_path, GOOD + "\n[self_collision]\nthickness = 0.004\ncontinuous = false\n")).scene
    obj = sc.controller("colliders").self_collision
    assert (obj.thickness, obj.continuous, obj.friction) == (0.004, False, 0.1)
    misspelled = r"\[self_collision\]: unknown key 'continous' \(did you mean 'continuous'\?\)"
    with pytest.raises(tc.SceneError, match=misspelled):
        tc.load_scene(write(tmp_path, GOOD + "\n[self_collision]\ncontinous = false\n"))


def test_colliders_from_a_file(tmp_path):
    text = GOOD + """
self_collision = true
[[colliders]]
type = "mesh"
path = "mannequin"
mode = "exact"
repulsion = { stiffness = 1e-4, distance = 0.005 }
[[colliders]]
type = "sphere"
center = [0.0, 0.5, 0.0]
radius = 0.2
[[colliders]]
type = "plane"
point = [0.0, 0.0, 0.0]
normal = [0.0, 1.0, 0.0]
friction = 0.8
"""
    sc = tc.load_scene(write(tmp_path, text.replace('name = "t"\n', 'name = "t"\nself_collision = true\n', 1)
                             .replace("\nself_collision = true\n[[colliders]]", "\n[[colliders]]", 1))).scene
    colliders = sc.controller("colliders").objects
    kinds = [type(c).__name__ for c in colliders]
    assert kinds == ["MeshCollider", "PrimitiveColliders", "PrimitiveColliders", "SelfCollision"]
    assert colliders[0].mode == "exact" and colliders[0].repulsion.distance == 0.005
    assert colliders[2].friction == 0.8 and colliders[1].n_spheres == 1
    assert sc.forces.sources == (colliders[0].repulsion,)


def test_overrides_replace_integrator_and_step(tmp_path):
    path = write(tmp_path, GOOD.replace('dt = 0.005', 'dt = 0.005\nsweeps = 4\njv_term = true'))
    loaded = tc.load_scene(path, integrator="implicit", dt=0.01, frames=7)
    assert loaded.scene.integrator.name == "implicit" and loaded.scene.dt == 0.01 and loaded.frames == 7
    # the file's approx-implicit options do not follow the override to another integrator
    assert "sweeps" not in loaded.scene.integrator.options


@pytest.mark.parametrize("edit,expected", [
    (("frames = 3", "frames = 3\nframse = 4"), "unknown key 'framse' (did you mean 'frames'?)"),
    (("size = [0.5, 0.5]", "size = [0.5, 0.5]\nsise = 1"), "[cloth.grid]: unknown key 'sise'"),
    (('dt = 0.005', 'dt = "fast"'), "[integrator] dt: must be a number of seconds or \"auto\", got 'fast'"),
    (('dt = 0.005', 'dt = -0.001'), "[integrator] dt: must be > 0, got -0.001"),
    (('dt = 0.005', ''), "[integrator]: missing required key 'dt'"),
    (('name = "approx-implicit"', 'name = "rk4"'), "[integrator] name: 'rk4' is not one of: explicit"),
    (('dt = 0.005', 'dt = 0.005\nsweeps = 2.5'), "[integrator] sweeps: must be an integer, got 2.5"),
    (('dt = 0.005', 'dt = 0.005\ncg_tolerance = 1e-3'), "unknown key 'cg_tolerance' for integrator 'approx-implicit'"),
    (('resolution = [6, 6]', 'resolution = [6, 1]'), "[cloth.grid] resolution: must be >= 2 each"),
    (('material = "silk"', 'material = "velvet"'), "[cloth] material: 'velvet' is not one of: silk"),
    (('[cloth.grid]', '[cloth.mesh]\npath = "x.obj"\n[cloth.grid]'),
     "needs exactly one source: [cloth.grid], [cloth.mesh] or garment"),
    (('near = [[-0.25, 1.25, 0.0], [0.25, 1.25, 0.0]]', 'near = [1, 2]'),
     "[[pins]] #1 near: must be a list of [x, y, z]"),
    (('near = [[-0.25, 1.25, 0.0], [0.25, 1.25, 0.0]]', 'keyframes = [[0, 0, 0, 0]]'), "[[pins]] #1: selects nothing"),
    (('frames = 3', 'frames = 3\n[wind]\ncoefficient = 1.0'), "[wind]: missing required key 'velocity'"),
    (('[integrator]\nname = "approx-implicit"\ndt = 0.005', ''), "missing required table [integrator]"),
    (('frames = 3', 'frames = 3\n[stretch_limit]\nomega = 2.5'), "[stretch_limit] omega: must lie in (0, 2)"),
    (('frames = 3', 'frames = 3\n[[colliders]]\ntype = "sphere"\ncenter = [0, 0, 0]'),
     "[[colliders]] #1: a sphere collider needs 'radius'"),
    (('frames = 3', 'frames = 3\n[[colliders]]\ntype = "plane"\npoint = [0, 0, 0]\nnormal = [0, 1, 0]\nradius = 1'),
     "[[colliders]] #1: 'radius' is not a plane collider key"),
    (('frames = 3', 'frames = 3\n[[colliders]]\ntype = "cube"'), "[[colliders]] #1 type: 'cube' is not one of: sphere"),
    (('frames = 3', 'frames = 3\n[sewing]\ngravity = true'), "[sewing]: needs a garment cloth"),
    (('frames = 3', 'frames = 3\nself_collision = "yes"'), "self_collision: must be true or false"),
    (('[cloth]', '[cloth]\nresolution = "fit"'), "[cloth] resolution: is a garment's preset"),
    (('[cloth]', '[cloth]\nresolution = "coarse"'), "[cloth] resolution: 'coarse' is not one of: draft"),
])
def test_each_mistake_names_its_key(tmp_path, edit, expected):
    old, new = edit
    assert old in GOOD
    path = write(tmp_path, GOOD.replace(old, new, 1))
    with pytest.raises(tc.SceneError) as err:
        parse_scene(path)
    text = str(err.value)
    assert expected in text and text.startswith(str(path)) and "\n" not in text


def test_unreadable_files(tmp_path):
    with pytest.raises(tc.SceneError, match="no such scene file"):
        parse_scene(tmp_path / "nope.toml")
    with pytest.raises(tc.SceneError, match="not valid TOML"):
        parse_scene(write(tmp_path, "name = [unclosed"))
    bad_mesh = GOOD.replace('[cloth.grid]\nsize = [0.5, 0.5]\nresolution = [6, 6]\ncenter = [0.0, 1.0, 0.0]',
                            '[cloth.mesh]\npath = "missing.obj"')
    with pytest.raises(tc.SceneError, match=r"\[cloth.mesh\] path: .*no such mesh file"):
        tc.load_scene(write(tmp_path, bad_mesh))


def test_cli_prints_one_line_and_exits_2(tmp_path, capsys):
    path = write(tmp_path, GOOD.replace("dt = 0.005", "dt = -1"))
    assert main(["run", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "[integrator] dt" in err[0]
    assert main(["run", str(write(tmp_path, GOOD, "g.toml")), "--integrator", "rk4"]) == 2
    assert "--integrator" in capsys.readouterr().err


# ------------------------------------------------------------------------------ the Python API checks the same
SHEET_ONLY = GOOD.split("[[pins]]")[0]


@pytest.mark.parametrize("kind, entry, toml, expected", [
    ("colliders", {"type": "sphere", "center": (0, 0, 0), "radius": 0.1, "bogus": 1},
     'type = "sphere"\ncenter = [0, 0, 0]\nradius = 0.1\nbogus = 1',
     "[[colliders]] #1: unknown key 'bogus' (known keys"),
    ("colliders", {"type": "sphere", "center": (0, 0, 0), "radus": 0.1},
     'type = "sphere"\ncenter = [0, 0, 0]\nradus = 0.1',
     "[[colliders]] #1: unknown key 'radus' (did you mean 'radius'?)"),
    ("colliders", {"type": "sphere", "center": (0, 0, 0)},
     'type = "sphere"\ncenter = [0, 0, 0]', "[[colliders]] #1: a sphere collider needs 'radius'"),
    ("colliders", {"type": "plane", "point": (0, 0, 0), "normal": (0, 0, 0)},
     'type = "plane"\npoint = [0, 0, 0]\nnormal = [0, 0, 0]',
     "[[colliders]] #1 normal: must be non-zero (a direction), got [0, 0, 0]"),
    ("colliders", {"type": "mesh", "path": "mannequin", "thickness": 0},
     'type = "mesh"\npath = "mannequin"\nthickness = 0',
     "[[colliders]] #1 thickness: must be > 0 for a mesh collider, got 0.0"),
    ("colliders", {"type": "sphere", "center": (0, 0, 0), "radius": -1},
     'type = "sphere"\ncenter = [0, 0, 0]\nradius = -1', "[[colliders]] #1 radius: must be > 0, got -1.0"),
    ("pins", {"indics": [0]}, "indics = [0]", "[[pins]] #1: unknown key 'indics' (did you mean 'indices'?)"),
    ("pins", {"keyframes": [[0, 0, 0, 0]]}, "keyframes = [[0, 0, 0, 0]]",
     "[[pins]] #1: selects nothing: give indices, near or box"),
    ("pins", {"indices": [0], "keyframes": [[1, 0, 0, 0], [0, 0, 0.1, 0]]},
     "indices = [0]\nkeyframes = [[1, 0, 0, 0], [0, 0, 0.1, 0]]",
     "[[pins]] #1 keyframes: times must increase strictly"),
    ("pins", {"indices": [0], "keyframes": [[0, 0, 0]]}, "indices = [0]\nkeyframes = [[0, 0, 0]]",
     "[[pins]] #1 keyframes: must be a list of [t, dx, dy, dz] rows, got [[0, 0, 0]]"),
])
def test_a_dict_of_the_python_api_gets_the_scene_files_line(tmp_path, kind, entry, toml, expected):
    """One validator (taichi_cloth.specs) for a scene file's [[colliders]] / [[pins]] and the dicts of
    Scene(colliders=..., pins=...): the same mistake gets the same line, the file's name in front of it. Before, a
    dict with an unknown key was accepted without a word and a misspelled one ended in a bare KeyError."""
    path = write(tmp_path, f"{SHEET_ONLY}\n[[{kind}]]\n{toml}\n")
    with pytest.raises(tc.SceneError) as in_file:
        parse_scene(path)
    assert str(in_file.value).startswith(f"{path}: {expected}")
    cloth = tc.ClothBuilder.grid((0.5, 0.5), (6, 6), center=(0.0, 1.0, 0.0))
    with pytest.raises(tc.SceneError) as in_python:
        tc.Scene(cloth, integrator="approx-implicit", dt=0.005, **{kind: [entry]})
    assert str(in_python.value) == str(in_file.value).removeprefix(f"{path}: ")


def test_a_pin_dict_moves_by_keyframes_and_the_old_name_path_still_works():
    """A pin's motion is `keyframes` in both paths (a dict with keyframes ended in a TypeError from PinSpec); the
    Python name it had, `path`, works with a DeprecationWarning pointing to the new name."""
    cloth = tc.ClothBuilder.grid((0.5, 0.5), (6, 6), center=(0.0, 1.0, 0.0))
    rows = [[0.0, 0, 0, 0], [1.0, 0.1, 0, 0]]
    box = {"box": {"min": [-1, 1.2, -1], "max": [1, 1.3, 1]}}
    sc = tc.Scene(cloth, integrator="approx-implicit", dt=0.005, pins=[{"indices": [0], "keyframes": rows}, box])
    assert sc.controller("pins").moving and sc.model.pinned.sum() == 7
    with pytest.warns(DeprecationWarning, match=r"\[\[pins\]\] #1: a pin's 'path' is now called 'keyframes'"):
        sc = tc.Scene(cloth, integrator="approx-implicit", dt=0.005, pins=[{"indices": [0], "path": rows}])
    assert sc.controller("pins").moving
    with pytest.warns(DeprecationWarning, match=r"PinSpec\(path=...\) is now PinSpec\(keyframes=...\)"):
        spec = tc.PinSpec(indices=[0], path=rows)
    assert spec.keyframes(0.5) == pytest.approx([0.05, 0, 0])
    with pytest.warns(DeprecationWarning, match=r"PinSpec.path is now PinSpec.keyframes"):
        assert spec.path is spec.keyframes
    with pytest.raises(tc.SceneError, match=r"^\[\[pins\]\] #1: give keyframes, not both keyframes and path"):
        tc.Scene(cloth, pins=[{"indices": [0], "path": rows, "keyframes": rows}])


def test_a_sphere_capsule_or_plane_may_have_no_thickness_in_both_paths(tmp_path):
    """What the colliders accept, both paths accept: a primitive's thickness may be 0 (a benchmark compares with a
    peer that tests |x - c| <= r), a mesh's may not (above)."""
    cfg = parse_scene(write(tmp_path, f'{SHEET_ONLY}\n[[colliders]]\ntype = "plane"\npoint = [0, 0, 0]\n'
                                      'normal = [0, 1, 0]\nthickness = 0\n'))
    assert cfg["colliders"][0]["thickness"] == 0.0
    sc = tc.Scene(tc.ClothBuilder.grid((0.5, 0.5), (6, 6), center=(0.0, 1.0, 0.0)), integrator="approx-implicit",
                  dt=0.005, colliders=[{"type": "sphere", "center": (0, 0, 0), "radius": 0.1, "thickness": 0.0}])
    assert sc.controller("colliders").objects[0].thickness == 0.0
