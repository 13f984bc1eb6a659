"""Bad input as a user gives it: each kind gets one `error:` line (exit 2) or one `warning:` line, never a traceback
or a crash; Ctrl-C ends a command with one `interrupted:` line (exit 130) and keeps what was written. A command
refused before any Taichi work (bad arguments, bad files, the guards that refuse before anything is allocated,
output folders that cannot be written) runs in this process (`run_main`: taichi_cloth.cli.main, a second each
saved); one that builds or runs a scene, or whose point is the process (Ctrl-C, a long run, the GPU fallback, a
demo script's own exit), runs `python -m taichi_cloth` (or a demo script) in a subprocess (`cli`, `demo`)."""
import errno
import os
import re
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import ezdxf
import numpy as np
import pytest

from clothbase.errors import EngineWarning
from taichi_cloth import guards
from taichi_cloth.errors import SceneError
from taichi_cloth.garment.dxf import read_dxf

ROOT = Path(__file__).resolve().parents[1]

GRID = """
name = "t"
frames = {frames}
[cloth]
{material}
[cloth.grid]
size = [1.0, 1.0]
resolution = [{res}, {res}]
center = [0.0, 1.5, 0.0]
plane = "xz"
[integrator]
name = "{integrator}"
dt = {dt}
[output]
dir = "{out}"
record = false
mesh = false
"""


def scene_file(tmp_path, name="scene.toml", res=6, frames=1, dt=0.001, integrator="explicit", out=None,
               material='material = "cotton"', extra=""):
    path = tmp_path / name
    path.write_text(GRID.format(res=res, frames=frames, dt=dt, integrator=integrator, material=material,
                                out=out or (tmp_path / "out").as_posix()) + extra)
    return path


def cli(*args, cwd=None, timeout=300, code=None):
    """(exit code, stdout, stderr lines other than Taichi's own banner and log lines). `code`: Python run instead of
    `-m taichi_cloth` (it calls taichi_cloth.cli.main itself, after faking what a test fakes)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    start = ["-c", code] if code is not None else ["-m", "taichi_cloth"]
    done = subprocess.run([sys.executable, *start, *map(str, args)], capture_output=True, text=True,
                          cwd=cwd or ROOT, env=env, timeout=timeout)
    noise = ("[Taichi]", "[W ", "[I ")
    err = [line for line in done.stderr.splitlines() if line.strip() and not line.startswith(noise)]
    return done.returncode, done.stdout, err


def demo(name, *args, timeout=300):
    """cli's (exit code, stdout, stderr lines) of the demo script demos/NAME.py."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    done = subprocess.run([sys.executable, str(ROOT / "demos" / f"{name}.py"), *map(str, args)], capture_output=True,
                          text=True, cwd=ROOT, env=env, timeout=timeout)
    noise = ("[Taichi]", "[W ", "[I ")
    return done.returncode, done.stdout, [line for line in done.stderr.splitlines()
                                          if line.strip() and not line.startswith(noise)]


def _fresh_warning_filters() -> None:
    """The warning filters of a fresh `python -m taichi_cloth`: Python's defaults, Taichi's deprecations and the
    engine's warnings once (clothbase.errors); pytest's own filters would hide some of what a user sees."""
    warnings.resetwarnings()
    for category in (ResourceWarning, ImportWarning, PendingDeprecationWarning, DeprecationWarning):
        warnings.simplefilter("ignore", category)
    warnings.filterwarnings("once", category=DeprecationWarning, module="taichi")
    warnings.filterwarnings("once", category=EngineWarning)


@pytest.fixture
def run_main(monkeypatch, capsys):
    """cli() in this process, for a command refused before a step runs (some build the scene's fields first, which
    the session's CPU runtime takes in its stride): `run_main(*args, cwd=None)` calls
    taichi_cloth.cli.main(args) in `cwd` (default the repository, as cli) and returns cli's (exit code, stdout,
    stderr lines). What a process would show is kept: argparse's SystemExit is its exit code (its usage and
    `error:` lines on stderr), the warnings a fresh interpreter prints are stderr lines (`warning: ...`), an
    uncaught exception fails the test (a process would end in a traceback). The session's Taichi runtime (ti.cpu,
    tests/conftest.py) must survive: a command that starts Taichi on another arch fails the test instead of
    re-initialising it (which frees every field); the cwd and runtime's parallel_from are restored after the test."""
    from taichi_cloth import cli as cli_module
    from taichi_cloth import runtime

    init = runtime.init

    def cpu_only(arch="cpu", *args, **kwargs):
        assert arch == "cpu", f"runtime.init({arch!r}) in the test process: run this command with cli()"
        return init(arch, *args, **kwargs)

    monkeypatch.setattr(runtime, "init", cpu_only)
    monkeypatch.setattr(runtime, "_parallel_from", runtime._parallel_from)

    def call(*args, cwd=None):
        monkeypatch.chdir(cwd or ROOT)
        capsys.readouterr()  # what came before is not this command's
        with warnings.catch_warnings(record=True) as caught:
            _fresh_warning_filters()
            try:
                rc = cli_module.main(list(map(str, args)))
            except SystemExit as exc:  # as the interpreter ends on it: None is 0, a message is printed and 1
                rc = 0 if exc.code is None else exc.code if isinstance(exc.code, int) else 1
                if exc.code is not None and not isinstance(exc.code, int):
                    print(exc.code, file=sys.stderr)
        captured = capsys.readouterr()
        shown = [line for w in caught for line in
                 ([f"warning: {w.message}"] if issubclass(w.category, EngineWarning) else
                  warnings.formatwarning(w.message, w.category, w.filename, w.lineno, w.line).splitlines())]
        noise = ("[Taichi]", "[W ", "[I ")
        err = shown + [line for line in captured.err.splitlines() if line.strip() and not line.startswith(noise)]
        return rc, captured.out, err

    return call


def one_error(rc, err, *words):
    assert rc == 2, err
    assert len(err) == 1 and err[0].startswith("error: "), err
    for w in words:
        assert w in err[0], err[0]
    return err[0]


def one_clean_error(rc, out, err, *words):
    """one_error, and nothing on stdout that belongs on stderr (an `error:` line, a traceback)."""
    assert "Traceback" not in out and "error:" not in out, out
    return one_error(rc, err, *words)


# ------------------------------------------------------------------------------------------------ resources
@pytest.mark.parametrize("res, particles", [(30000, "900,000,000"), (100000, "10,000,000,000")])
def test_a_huge_grid_is_refused_before_anything_is_allocated(tmp_path, res, particles, run_main):
    rc, _, err = run_main("run", scene_file(tmp_path, res=res), "--no-progress")
    one_error(rc, err, f"[cloth.grid] resolution {res} x {res}", f"{particles} particles need about",
              "TiB of memory (estimate", "available; use a coarser resolution")


def test_memory_guard_against_a_given_machine():
    guards.check_memory(1000, "x", available=1000 * guards.BYTES_PER_PARTICLE)  # fits exactly
    with pytest.raises(SceneError, match=r"^x: 1,001 particles need about 5.87 MiB .* this machine has 5.86 MiB"):
        guards.check_memory(1001, "x", available=1000 * guards.BYTES_PER_PARTICLE)


def test_a_garment_spacing_the_machine_cannot_mesh_is_refused_before_meshing(tmp_path):
    """A tiny garment spacing means billions of particles: refused before the pieces are meshed (or the body is
    analysed), naming the garment, the spacing and the estimate; from a scene file, with the garment file's name."""
    import taichi_cloth as tc
    from taichi_cloth.errors import PatternError
    from taichi_cloth.garment.garment import build_garment
    from taichi_cloth.garment.garmentfile import load_garment

    spec = load_garment(ROOT / "demos/garments/tshirt.toml")
    assert guards.sheet_particles(sum(p.area() for p in spec.pieces), sum(p.perimeter() for p in spec.pieces),
                                  0.01) == pytest.approx(5541, rel=0.1)  # the 1 cm T-shirt's pieces: 5,541
    spec.spacing = 1e-5
    with pytest.raises(PatternError, match=r"^garment 'tshirt': spacing 1e-05 m: 5,244,\d{3},\d{3} particles need "
                                           r"about 29.3 TiB of memory \(estimate.*; use a larger spacing"):
        build_garment(spec)
    garment = (ROOT / "demos/garments/tshirt.toml").read_text().replace("spacing = 2.0", "spacing = 0.001")
    assert garment != (ROOT / "demos/garments/tshirt.toml").read_text()
    (tmp_path / "tiny.toml").write_text(garment)
    scene = (ROOT / "demos/scenes/sew_tshirt.toml").read_text().replace("../garments/tshirt.toml", "tiny.toml")
    (tmp_path / "scene.toml").write_text(scene)
    with pytest.raises(SceneError, match=r"scene.toml: \[cloth\] garment tiny.toml: garment 'tshirt': spacing 1e-05 m"):
        tc.load_scene(tmp_path / "scene.toml")


def test_a_collider_cell_size_the_machine_cannot_hold_is_refused_before_the_grid_is_built(tmp_path):
    """A tiny voxel over the mannequin is a grid of trillions of cells: refused naming the collider, its cell_size
    and the estimate, from a scene file and from a dict alike."""
    import taichi_cloth as tc

    cell = "cell_size 0.0001 m (mesh mannequin): a voxel grid of 2,012,427,431,910 cells and 94,350,409,659 " \
           "triangle-cell pairs needs about 15.2 TiB of memory (estimate)"
    path = scene_file(tmp_path, extra='\n[[colliders]]\ntype = "mesh"\npath = "mannequin"\ncell_size = 1e-4\n')
    with pytest.raises(SceneError, match=rf"scene.toml: \[\[colliders\]\] #1 {re.escape(cell)}"):
        tc.load_scene(path)
    with pytest.raises(SceneError, match=rf"^\[\[colliders\]\] #2 {re.escape(cell)}.*; use a larger cell_size"):
        tc.Scene(tc.ClothBuilder.grid((0.2, 0.2), (4, 4)),
                 colliders=[{"type": "standin"}, {"type": "mesh", "path": "mannequin", "cell_size": 1e-4}])
    cells, pairs = guards.voxel_grid_size(np.eye(3), np.array([[0, 1, 2]]), 0.5, 0.0, 0.0)
    # collision.grid.VoxelGrid's count: ceil(1.25 x 1 m / 0.5 m) + 2 = 5 cells per axis; the triangle's box over
    # 0..1 m meets cells 0, 1 and 2 (its upper face lies on a cell boundary) per axis
    assert (cells, pairs) == (5 ** 3, 3 ** 3)


def test_a_self_collision_cell_size_the_machine_cannot_hold_is_refused_before_the_grid_is_built():
    """Self-collision's hashed grid is sized for the cloth in any pose: a 10 um cell over a 2 cm sheet asks for
    trillions of pairs, refused naming the key; the default cell builds."""
    import taichi_cloth as tc

    sheet = tc.ClothBuilder.grid((0.2, 0.2), (11, 11))
    with pytest.raises(SceneError, match=r"^self_collision cell_size 1e-05 m: a voxel grid of [\d,]+ cells and "
                                         r"[\d,]+ triangle-cell pairs .*use a larger cell_size"):
        tc.Scene(sheet, self_collision={"cell_size": 1e-5})
    tc.Scene(sheet, self_collision={"cell_size": 0.03})


def test_a_tiny_step_is_refused_with_its_count_and_time(run_main, tmp_path):
    path = scene_file(tmp_path, dt=1e-12, frames=2)
    rc, _, err = run_main("run", path, "--no-progress")
    one_error(rc, err, "the run is too long: 2 frames of 16,666,650,000 steps (dt = 1e-12 s) = 33,333,300,000 steps",
              "on this CPU (estimate)", "more than 10,000,000 steps needs --yes")


def test_a_long_run_is_announced_and_runs_with_yes(tmp_path):
    # 20 frames of 2,000,000 steps: refused without --yes, announced with it (and stopped by the timeout here)
    path = scene_file(tmp_path, dt=1e-8, frames=20)
    rc, _, err = cli("run", path, "--no-progress")
    one_error(rc, err, "= 33,333,300 steps", "needs --yes")
    env = dict(os.environ, PYTHONPATH=str(ROOT), PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([sys.executable, "-m", "taichi_cloth", "run", str(path), "--no-progress", "--yes"],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, cwd=ROOT, env=env)
    try:
        line = next(text for text in proc.stdout if not text.startswith("[Taichi]"))
    finally:
        proc.kill()
        proc.wait()
    assert line.startswith("this run takes 20 frames of 1,666,665 steps (dt = 1e-08 s) = 33,333,300 steps, about ")


def test_an_automatic_step_is_counted_too(run_main, tmp_path):
    """dt = "auto" (here from --quality accurate: central differences at 0.9 x the stable step) was skipped by the
    run-length guard: a stiff fine scene ran for hours unannounced. Its steps now come from the clock's own rule."""
    stiff = 'material = { preset = "cotton", stretch = 1e6, shear = 1e6 }'
    rc, _, err = run_main("run", scene_file(tmp_path, res=32, frames=1000, material=stiff), "--no-progress",
                     "--quality", "accurate")
    one_error(rc, err, "the run is too long: 1000 frames of 10,617 steps (dt = auto: 1.57e-06 s, 0.9 x the stable "
                       "step 1.74e-06 s) = 10,617,000 steps at least, about ", "needs --yes")


def test_the_run_length_of_a_coarse_to_fine_cloth_is_that_of_its_finest_level():
    """A multilevel cloth runs most of its steps on its finest level: the estimate takes its particles and, with
    dt = "auto", its stable step, not those of the level the run starts on (the 5 mm T-shirt coarse to fine starts
    on 5,541 particles, refines to 21,176, and was announced as the 5,541)."""
    import taichi_cloth as tc

    def scene(start):
        cloth = tc.ClothBuilder.multilevel_grid((1.0, 1.0), (4, 4), 5, start_level=start)
        return tc.Scene(cloth, integrator="explicit", dt="auto", pins=[{"near": [[-0.5, 0.5, 0], [0.5, 0.5, 0]]}])

    coarse, fine = scene(0), scene(4)
    assert coarse.model.data.n_particles < fine.model.data.n_particles == fine.model.capacity[0]
    assert coarse.clock.substeps < fine.clock.substeps == guards.frame_plan(coarse)[0]
    assert guards.frame_plan(coarse)[1] == pytest.approx(guards.frame_plan(fine)[1], rel=1e-9)
    assert "of the finest level" in guards.frame_plan(coarse)[2]
    assert guards.seconds_per_step(coarse) == guards.seconds_per_step(fine)


def test_the_implicit_cost_per_particle_grows_with_the_cg_iterations():
    """The implicit step's cost per particle is not one figure measured at one size: Jacobi's CG iterations grow
    with the size (up to the cap), a cap raised lets them, and the collision stage costs per particle too."""
    import taichi_cloth as tc

    def sheet(**options):
        return tc.Scene(tc.ClothBuilder.grid((1.0, 1.0), (8, 8)), integrator="implicit", dt=1 / 60, **options)

    jacobi = sheet(integrator_options={"preconditioner": "jacobi"})
    small, large = guards.implicit_cost(jacobi, 100)[0], guards.implicit_cost(jacobi, 10_000)[0]
    assert small == pytest.approx(5e-7 + 40 * 3e-8) and large == pytest.approx(5e-7 + 200 * 3e-8)  # 200: the cap
    raised = sheet(integrator_options={"preconditioner": "jacobi", "cg_max_iterations": 1000})
    assert guards.implicit_cost(raised, 40_000)[0] == pytest.approx(5e-7 + 420 * 3e-8)  # 13 us, above the 8 it was
    assert guards.implicit_cost(sheet(), 10_000)[0] == pytest.approx(5e-7 + 25 * 1.3e-7)  # auto: aggregation there
    body = sheet(colliders=[{"type": "mesh", "path": "mannequin"}])
    assert guards.seconds_per_step(body) - guards.seconds_per_step(sheet()) == pytest.approx(
        64 * guards.MESH_COLLIDER_SECONDS_PER_PARTICLE + guards.SECONDS_PER_STEP_MESH_COLLIDER)


# ------------------------------------------------------------------------------------------------ precision
STIFF = 'material = { preset = "cotton", stretch = 1e14, shear = 1e14 }'


def test_f32_refuses_a_stiffness_it_cannot_resolve(run_main, tmp_path):
    path = scene_file(tmp_path, res=8, integrator="implicit", dt=0.016666667, material=STIFF)
    rc, _, err = run_main("run", path, "--no-progress")
    one_error(rc, err, "f32 cannot resolve this step: h^2 k / m = ", "exceeds 8.39e+05 = 0.1 / f32 epsilon",
              'use precision = "f64" (--precision f64)')


def test_stiffness_ratio_reads_the_stiffest_spring_against_the_lightest_particle(tmp_path):
    import taichi_cloth as tc

    loaded = tc.load_scene(scene_file(tmp_path, res=8, integrator="implicit", dt=0.01, material=STIFF),
                           precision="f64")
    d = loaded.scene.model.data
    m = np.minimum(d.mass[d.springs[:, 0]], d.mass[d.springs[:, 1]])
    assert guards.stiffness_ratio(loaded.scene) == pytest.approx(float(np.max(1e-4 * d.stiffness / m)), rel=1e-12)
    assert guards.stiffness_ratio(loaded.scene) > 0.1 / guards.EPSILON["f32"]  # f64 accepted it (no error)
    with pytest.raises(SceneError, match="f32 cannot resolve this step"):
        guards.check_precision(loaded.scene, "f32")


def test_demo_scenes_are_far_inside_the_f32_limit():
    import taichi_cloth as tc

    loaded = tc.load_scene(ROOT / "demos/scenes/hanging_cloth.toml")
    assert guards.stiffness_ratio(loaded.scene) * guards.EPSILON["f32"] < 1e-2 * guards.MASS_DIGITS


# ------------------------------------------------------------------------------------------------ meshes
COLLIDER = '\n[[colliders]]\ntype = "mesh"\npath = "{path}"\n'


def test_an_open_collider_mesh_warns_that_it_is_one_sided(tmp_path):
    (tmp_path / "open.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n")
    path = scene_file(tmp_path, extra=COLLIDER.format(path="open.obj"))
    rc, _, err = cli("run", path, "--no-progress")
    assert rc == 0, err
    assert err == ["warning: open.obj: the collider mesh is open (4 boundary edges, not watertight): "
                   "it acts as a one-sided collider; cloth that passes an edge or a hole is not pushed back out, "
                   "since an open mesh has no inside"]


@pytest.mark.parametrize("name, content, words", [
    ("latin.obj", b"h\xe9llo w\xf6rld\nthis is no mesh\n", "unreadable as a mesh: no vertices found in it"),
    ("notes.stl", b"just some text\n", "unreadable as a mesh"),
    ("pattern.dxf", (ROOT / "demos/garments/top.dxf").read_bytes(), "unreadable as a mesh: a DXF file holds 2D "
                                                                     "pattern outlines, not triangles"),
])
def test_an_unreadable_mesh_file_is_reported_as_unreadable(run_main, tmp_path, name, content, words):
    (tmp_path / name).write_bytes(content)
    path = scene_file(tmp_path, extra=COLLIDER.format(path=name))
    rc, _, err = run_main("run", path, "--no-progress")
    line = one_error(rc, err, str(tmp_path / name), words)
    assert "charset_normalizer" not in line and "reshape" not in line


def test_the_text_decoder_of_the_mesh_reader_is_installed():
    import charset_normalizer  # noqa: F401  (trimesh decodes non-UTF-8 text meshes with it)


# ------------------------------------------------------------------------------------------------ no GPU
#: the CLI in a process where the GPU probes answer as faked: `loader` (the Vulkan loader found: Taichi's
#: is_arch_supported(ti.vulkan) says yes) and `device` (the device probe's answer); CUDA and Metal absent
FAKE_GPU = ("import sys, taichi as ti; from taichi_cloth import runtime; "
            "runtime.is_arch_supported = lambda arch: {loader} and arch == ti.vulkan; "
            "runtime.vulkan_device_usable = lambda: {device}; "
            "from taichi_cloth.cli import main; sys.exit(main())")


@pytest.mark.parametrize("loader, why", [
    (False, ""),
    (True, "; the Vulkan loader is installed but finds no usable device"),
])
def test_gpu_without_a_gpu_falls_back_to_the_cpu_with_one_line(tmp_path, loader, why):
    """--arch gpu on a machine without a GPU, faked (so it is tested on every machine, one with a GPU included): no
    backend at all, or a Vulkan loader whose device probe fails (Taichi's own check finds the loader, not a device,
    and reported it as a GPU). Either way the run goes on on the CPU with one warning line."""
    rc, out, err = cli("run", scene_file(tmp_path), "--no-progress", "--arch", "gpu",
                       code=FAKE_GPU.format(loader=loader, device=False))
    assert rc == 0, err  # not 139 (the segmentation fault of probing OpenGL)
    assert err == [f"warning: no GPU found (no CUDA, Vulkan or Metal device{why}): running on the CPU"]
    assert "ran 1 frames" in out


# ------------------------------------------------------------------------------------------------ paths
def test_an_output_dir_that_is_a_file_is_refused_before_the_scene_is_built(tmp_path, run_main):
    (tmp_path / "taken").write_text("a file")
    rc, _, err = run_main("run", scene_file(tmp_path, out=(tmp_path / "taken").as_posix()), "--no-progress")
    one_error(rc, err, f"[output] dir '{(tmp_path / 'taken').as_posix()}' is a file, not a folder")
    rc, _, err = run_main("run", scene_file(tmp_path, out=(tmp_path / "taken" / "sub").as_posix()), "--no-progress")
    one_error(rc, err, f"lies below the file {tmp_path / 'taken'}")


def test_a_scene_or_mesh_path_that_is_a_folder_is_named_as_one(tmp_path, run_main):
    rc, out, err = run_main("run", tmp_path, "--no-progress")
    one_clean_error(rc, out, err, f"error: {tmp_path}: is a folder, not a scene file")
    rc, out, err = run_main("flatten", tmp_path, "--out", tmp_path / "x.dxf")
    one_clean_error(rc, out, err, f"error: {tmp_path}: is a folder, not a mesh file")


def _square(tmp_path):
    """A flat square of two triangles (a disc `flatten` takes)."""
    path = tmp_path / "square.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n")
    return path


def _output_command(kind, tmp_path, out, run_main):
    """How each kind of command is given the output folder `out`: (runner, arguments). The commands run in this
    process (run_main); the demo script in its own, as a user starts it (its exit code is the script's)."""
    return {"run": (run_main, ["run", scene_file(tmp_path), "--no-progress", "--out", out]),
            "flatten": (run_main, ["flatten", _square(tmp_path), "--out", out / "square.dxf"]),
            "bench": (run_main, ["bench", "--sizes", "4", "--integrators", "explicit", "--garment", "none",
                                 "--out", out]),
            "demo": (demo, ["hanging_cloth", "--frames", "1", "--no-progress", "--out", out])}[kind]


@pytest.mark.parametrize("kind", ["run", "flatten", "bench", "demo"])
def test_an_output_folder_below_a_file_is_refused_before_any_work(tmp_path, kind, run_main):
    (tmp_path / "notes.txt").write_text("a file")
    runner, args = _output_command(kind, tmp_path, tmp_path / "notes.txt" / "sub", run_main)
    rc, out, err = runner(*args)
    one_clean_error(rc, out, err, f"{tmp_path / 'notes.txt' / 'sub'}", f"lies below the file {tmp_path / 'notes.txt'}")


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into a read-only folder: chmod does not bite")
@pytest.mark.parametrize("kind", ["run", "flatten", "bench", "demo"])
def test_a_read_only_output_folder_is_refused_before_any_work(tmp_path, kind, run_main):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        runner, args = _output_command(kind, tmp_path, locked, run_main)
        rc, out, err = runner(*args)
    finally:
        locked.chmod(0o755)
    one_clean_error(rc, out, err, str(locked), "read-only folder (permission denied)")
    assert not any(locked.iterdir())


def test_a_full_disk_is_one_line_naming_the_file(monkeypatch, capsys):
    """A file-system error in the middle of a command (here a full disk while a run writes its recording: write()
    names no file) ends as one line naming the file the run was writing and the reason, exit 2."""
    from taichi_cloth import cli as cli_module

    def full(*_):
        exc = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        exc.output = "out/t.rrd"  # as taichi_cloth.run.run_scene_file marks what it was writing
        raise exc

    monkeypatch.setattr(cli_module, "run_scene_file", full)
    assert cli_module.main(["run", "t.toml"]) == 2
    captured = capsys.readouterr()
    assert captured.err.splitlines() == ["error: out/t.rrd: no space left on device"] and not captured.out

    def read_only():
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), "out/t.obj")

    assert cli_module.ends(read_only) == 2
    assert capsys.readouterr().err.splitlines() == ["error: out/t.obj: read-only file system"]


# ------------------------------------------------------------------------------------------------ bench arguments
@pytest.mark.parametrize("args, words", [
    (["--integrators", "explicit", "rk4"], "--integrators: unknown integrator 'rk4'; choose from explicit, verlet"),
    (["--sizes", "32", "1"], "--sizes: every n must be >= 4 (n x n particles), got 32 1"),
    (["--material", "velvet"], "--material: unknown material 'velvet'; choose from silk, cotton"),
    (["--garment", "missing.toml"], "--garment missing.toml: no such scene file"),
    # no implicit row would time the garment: the file named is still checked (issue 48: this ran silently)
    (["--sizes", "8", "--integrators", "explicit", "--garment", "missing.toml"],
     "--garment missing.toml: no such scene file"),
    (["collision", "--steps", "0"], "--steps must be >= 1 (the steps replayed), got 0"),
])
def test_bench_refuses_bad_arguments_before_it_starts(tmp_path, args, words, run_main):
    suite = ["collision"] if args[0] == "collision" else []
    rc, out, err = run_main("bench", *suite, *args[len(suite):], "--out", tmp_path / "bench", cwd=tmp_path)
    one_clean_error(rc, out, err, words)
    assert not (tmp_path / "bench").exists()  # refused before the output folder was made


@pytest.mark.parametrize("args, words", [(["tradeoff", "--variants", "rk4"], "unknown variant 'rk4'"),
                                         (["peers", "--sizes", "2"], "--sizes: every n must be >= 4")])
def test_every_bench_error_goes_to_stderr(tmp_path, args, words, run_main):
    rc, out, err = run_main("bench", *args, "--out", tmp_path / "bench")
    one_clean_error(rc, out, err, words)


# ------------------------------------------------------------------------------------------------ perturbed starts
@pytest.mark.parametrize("flags, words", [
    (["--perturb=-0.001"], "--perturb must be a distance >= 0 m, got -0.001"),
    (["--perturb", "nan"], "--perturb must be a distance >= 0 m, got nan"),
    (["--perturb", "inf", "--seed", "1"], "--perturb must be a distance >= 0 m, got inf"),
    (["--seed", "2"], "--seed 2: nothing to seed without --perturb METRES"),
])
def test_a_perturbation_that_is_no_distance_is_refused_before_taichi_starts(tmp_path, flags, words, run_main,
                                                                           monkeypatch):
    from taichi_cloth import runtime

    monkeypatch.setattr(runtime, "init", lambda *args, **kwargs: pytest.fail("Taichi started before the refusal"))
    rc, out, err = run_main("run", scene_file(tmp_path), "--no-progress", *flags)
    one_clean_error(rc, out, err, words)


# ------------------------------------------------------------------------------------------------ Ctrl-C
def test_ctrl_c_ends_a_run_with_one_line_and_keeps_its_recording(tmp_path):
    """SIGINT while a run records: exit 130, one `interrupted:` line naming the recording, no traceback, and the
    recording made so far stays on disk and reads back."""
    import rerun as rr

    path = scene_file(tmp_path, frames=100000)  # 1.7 million steps: minutes, stopped after the first frames
    path.write_text(path.read_text().replace("record = false", "record = true"))
    rrd = tmp_path / "out" / "t.rrd"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    # a terminal's Ctrl-C: SIGINT delivered (a shell starts background jobs with it ignored, and children inherit that)
    proc = subprocess.Popen([sys.executable, "-m", "taichi_cloth", "run", str(path), "--no-progress", "--yes"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT, env=env,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 120
        # frames are being written: a recording of this scene holds about 110 kB before its first frame (static
        # data, and the blueprint written on closing) and 1.5 kB a frame after
        while time.monotonic() < deadline and proc.poll() is None and not (rrd.exists() and rrd.stat().st_size > 4e5):
            time.sleep(0.1)
        assert proc.poll() is None, proc.communicate()
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    assert "Traceback" not in out + err
    lines = [line for line in err.splitlines() if line.strip() and not line.startswith(("[Taichi]", "[W ", "[I "))]
    assert lines == [f"interrupted: stopped by Ctrl-C; kept what was written to {rrd}"]
    frames = [c for c in rr.chunk.RrdReader(rrd).stream().to_chunks() if c.entity_path == "/cloth/mesh"
              and not c.is_static]
    assert frames  # the recording so far, closed and readable


# ------------------------------------------------------------------------------------------------ messages
@pytest.mark.parametrize("flag, value", [("--waist", "-5"), ("--waist", "0"), ("--hips", "nan"),
                                         ("--upper-arm", "inf")])
def test_body_girth_messages_speak_in_centimetres(tmp_path, flag, value, run_main):
    rc, _, err = run_main("body", flag, value, "--out", tmp_path / "b.obj")
    one_error(rc, err, f"{flag} must be a positive girth in cm, got {value}")


def test_a_pin_error_names_its_group(run_main, tmp_path):
    extra = "\n[[pins]]\nindices = [0]\n[[pins]]\nbox = { min = [5.0, 5.0, 5.0], max = [6.0, 6.0, 6.0] }\n"
    rc, _, err = run_main("run", scene_file(tmp_path, extra=extra), "--no-progress")
    one_error(rc, err, "[[pins]] #2: pin box [5.0, 5.0, 5.0]..[6.0, 6.0, 6.0] contains no particle")


def test_a_seam_corner_error_names_the_garment_file(tmp_path, run_main):
    garments = ROOT / "demos/garments"
    (tmp_path / "top.dxf").write_bytes((garments / "top.dxf").read_bytes())
    text = (garments / "top_dxf.toml").read_text().replace('from = "hem_L", to = "arm_L" }',
                                                            'from = "hem_X", to = "arm_L" }', 1)
    (tmp_path / "bad.toml").write_text(text)
    scene = (ROOT / "demos/scenes/sew_tshirt.toml").read_text().replace("../garments/tshirt.toml", "bad.toml")
    (tmp_path / "scene.toml").write_text(scene)
    rc, _, err = run_main("run", tmp_path / "scene.toml", "--no-progress", "--frames", "1")
    one_error(rc, err, "[cloth] garment bad.toml: seam 'left side': pattern piece 'front': no corner 'hem_X'")


def test_a_body_analysis_error_names_the_garment_and_the_body_file(monkeypatch):
    """A MeshError from the analysis of the body a garment is placed on names the garment and the body's file (it
    was reported as the scene's [cloth.mesh] path, which a garment scene does not have)."""
    import taichi_cloth as tc
    from collision.mannequin import DEFAULT_PATH
    from taichi_cloth.body import landmarks
    from taichi_cloth.errors import MeshError

    def no_armpit(*args):
        raise MeshError("body mesh: no armpit found below 90% of the height")

    monkeypatch.setattr(landmarks, "_armpit_height", no_armpit)
    scene = ROOT / "demos/scenes/sew_tshirt.toml"
    with pytest.raises(SceneError) as err:
        tc.load_scene(scene)
    assert str(err.value) == (f"{scene}: [cloth] garment ../garments/tshirt.toml: garment 'tshirt': placing its "
                              f"pieces on the body {DEFAULT_PATH}: no armpit found below 90% of the height")
    with pytest.raises(MeshError, match="^body mesh: no armpit"):  # a mesh of no file is still the body mesh
        landmarks.Body.from_mesh(np.eye(3), np.array([[0, 1, 2], [0, 2, 1]]))


# ------------------------------------------------------------------------------------------------ DXF corners
def test_dxf_corners_of_a_polyline_chained_with_a_spline(tmp_path):
    """side - hem - side as ONE open polyline, the top a spline: the hem corners are polyline vertices (90-degree
    turns) and become corners; a gently curved polyline keeps its vertices inside one segment."""
    doc = ezdxf.new("R2010")
    doc.units = 5  # cm
    msp = doc.modelspace()
    msp.add_lwpolyline([(0, 60), (0, 0), (40, 0), (40, 60)], dxfattribs={"layer": "front"})
    msp.add_open_spline([(40, 60, 0), (30, 70, 0), (10, 70, 0), (0, 60, 0)], degree=3, dxfattribs={"layer": "front"})
    msp.add_text("hem_L", dxfattribs={"layer": "front", "insert": (0, 0)})
    msp.add_text("hem_R", dxfattribs={"layer": "front", "insert": (40, 0)})
    # a curve drawn as a polyline (turns of 20 degrees) closed by a line
    arc = [(20 * np.cos(a), 20 * np.sin(a)) for a in np.radians(np.arange(0, 181, 20))]
    msp.add_lwpolyline(arc, dxfattribs={"layer": "round"})
    msp.add_line(arc[-1], arc[0], dxfattribs={"layer": "round"})
    doc.saveas(tmp_path / "chained.dxf")
    pieces = {p.name: p for p in read_dxf(tmp_path / "chained.dxf")}
    front = pieces["front"]
    assert front.corner_names == ["c0", "hem_L", "hem_R", "c3", ] and front.n_corners == 4
    assert [s.kind for s in front.segments] == ["line", "line", "line", "bspline"]
    np.testing.assert_allclose(front.corners, [[0, 0.6], [0, 0], [0.4, 0], [0.4, 0.6]], atol=1e-12)
    assert [s.kind for s in pieces["round"].segments] == ["polyline", "line"]
    # a seam can now be picked along the hem
    from taichi_cloth.garment.seams import Seam, SeamSide, route

    hem = route(front, Seam("hem", SeamSide("front", "hem_L", "hem_R"), SeamSide("front", "hem_L", "hem_R")),
                SeamSide("front", "hem_L", "hem_R"), np.array([s.length() for s in front.segments]))
    assert hem.segments == (1,) and hem.forward and hem.length == pytest.approx(0.4)
