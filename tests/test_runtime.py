"""Taichi start-up: a kernel-cache lock left by a killed process is cleared, a live one is not."""
import os
import time

import pytest

from taichi_cloth.runtime import STALE_LOCK_AGE, clear_stale_cache_lock


def test_a_stale_kernel_cache_lock_is_removed_and_a_fresh_one_kept(tmp_path):
    lock = tmp_path / "ticache.lock"
    lock.touch()
    clear_stale_cache_lock(tmp_path)  # just written: a live process may be writing the cache
    assert lock.exists()
    old = time.time() - STALE_LOCK_AGE - 60
    os.utime(lock, (old, old))
    with pytest.warns(UserWarning, match="stale kernel-cache lock"):
        clear_stale_cache_lock(tmp_path)
    assert not lock.exists()
    clear_stale_cache_lock(tmp_path)  # no lock: nothing to do


@pytest.mark.parametrize("integrator, serial", [("explicit", False), ("implicit", True), ("approx-implicit", True)])
def test_a_solve_runs_its_loops_in_one_thread_where_a_fused_explicit_step_does_not(integrator, serial, monkeypatch):
    """4,900 particles, above the explicit family's count (4,096; the solves' is "never"): a solve's loops run in
    one thread on the CPU, the explicit step's in parallel; TAICHI_CLOTH_PARALLEL_FROM sets one count for all.
    Building the scene compiles nothing."""
    import taichi_cloth as tc
    from taichi_cloth.runtime import PARALLEL_FROM_CPU, PARALLEL_FROM_CPU_SOLVE

    monkeypatch.delenv("TAICHI_CLOTH_PARALLEL_FROM", raising=False)
    cloth = tc.ClothBuilder.grid((1.0, 1.0), (70, 70), material="cotton")
    assert PARALLEL_FROM_CPU < cloth.n_particles < PARALLEL_FROM_CPU_SOLVE
    assert tc.Scene(cloth, integrator=integrator, dt=5e-5).model.serial is serial
    monkeypatch.setenv("TAICHI_CLOTH_PARALLEL_FROM", "100000")
    assert tc.Scene(cloth, integrator=integrator, dt=5e-5).model.serial is True


@pytest.mark.parametrize("usable", [False, True])
def test_a_vulkan_loader_without_a_device_is_no_gpu(monkeypatch, usable):
    """Taichi's is_arch_supported(ti.vulkan) finds the Vulkan loader, not a device: gpu_arch asks the device probe
    too, and falls back to the CPU with one warning line where the probe fails (faked here, both ways)."""
    import taichi as ti
    from taichi_cloth import runtime
    from taichi_cloth.errors import EngineWarning

    monkeypatch.setattr(runtime, "is_arch_supported", lambda arch: arch == ti.vulkan)  # the loader, nothing else
    monkeypatch.setattr(runtime, "vulkan_device_usable", lambda: usable)
    if usable:
        assert runtime.gpu_arch() == ti.vulkan
        return
    with pytest.warns(EngineWarning, match=r"^no GPU found \(no CUDA, Vulkan or Metal device; the Vulkan loader is "
                                           r"installed but finds no usable device\): running on the CPU$"):
        assert runtime.gpu_arch() == ti.cpu


@pytest.mark.parametrize("probe, usable", [("import sys; sys.exit(3)", False),
                                           ("import os, signal; os.kill(os.getpid(), signal.SIGKILL)", False),
                                           ("pass", True)])
def test_the_vulkan_probe_reads_its_child_process(monkeypatch, probe, usable):
    """The device probe is a child process (a driver that crashes must not take the run with it): a failing or
    crashing child is no device, a child that ran its kernel is one; the answer is kept for the process."""
    from taichi_cloth import runtime

    monkeypatch.setattr(runtime, "_VULKAN_PROBE", probe)
    monkeypatch.setattr(runtime, "_vulkan_usable", None)
    assert runtime.vulkan_device_usable() is usable
    monkeypatch.setattr(runtime, "_VULKAN_PROBE", "import sys; sys.exit(5)")
    assert runtime.vulkan_device_usable() is usable  # asked once


def test_the_front_end_without_wrapping_points_where_taichi_s_own_does_and_reads_a_source_once(monkeypatch):
    """taichi_cloth.taichi_frontend: the position message of every node of a function equals Taichi's own (lines under
    80 columns: nothing to wrap); a compile error names the line and marks the name; a function's source is read
    once however often it is inlined."""
    import ast
    import inspect
    import textwrap

    import taichi as ti
    from taichi.lang.ast.ast_transformer_utils import ASTTransformerContext

    import taichi_cloth as tc
    from taichi_cloth import taichi_frontend

    tc.init("cpu")
    assert taichi_frontend.install()  # runtime.init installed it (Taichi 1.7)
    assert ASTTransformerContext.get_pos_info is taichi_frontend.get_pos_info
    original = taichi_frontend._ORIGINAL_GET_POS_INFO

    class Context:  # what get_pos_info reads of Taichi's context
        def __init__(self, func):
            self.src = textwrap.dedent(inspect.getsource(func)).split("\n")
            self.file, self.lineno_offset, self.indent = "f.py", 0, 0
            self.func = type("F", (), {"func": func})

    def sample(a, b):
        for i in range(a):
            if i > b and (a
                          + b) > 0:
                a += b * i
        return a

    ctx = Context(sample)
    nodes = [n for n in ast.walk(ast.parse("\n".join(ctx.src))) if isinstance(n, (ast.stmt, ast.expr))]
    assert len(nodes) > 20
    for node in nodes:
        assert taichi_frontend.get_pos_info(ctx, node).replace(" \n", "\n").rstrip() \
            == original(ctx, node).replace(" \n", "\n").rstrip()

    x = ti.field(ti.f32, 4)

    @ti.func
    def helper(i):
        return x[i % 4] * 2.0

    @ti.kernel
    def fill():
        for i in x:
            x[i] = helper(i) + helper(i + 1) + not_defined_anywhere  # noqa: F821

    from taichi.lang import _wrap_inspect
    reads = []
    read = _wrap_inspect.getsourcelines
    monkeypatch.setattr(_wrap_inspect, "getsourcelines", lambda f: reads.append(f.__name__) or read(f))
    with pytest.raises(ti.TaichiNameError) as error:
        fill()
    message = str(error.value)
    assert "x[i] = helper(i) + helper(i + 1) + not_defined_anywhere" in message
    assert "^" * len("not_defined_anywhere") in message
    assert sorted(reads) == ["fill", "helper"]  # helper is inlined twice before the error, its source read once
