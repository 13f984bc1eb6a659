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
