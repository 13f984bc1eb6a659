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
