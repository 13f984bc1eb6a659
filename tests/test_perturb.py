"""`run --perturb METRES [--seed N]`: the start moved by a hair (taichi_cloth.perturb), the same for the same seed and
another for another, bit for bit; the summary says so. Its refusals are in test_hardening.py."""
import argparse

import numpy as np

from taichi_cloth.cli import add_run_arguments
from taichi_cloth.run import run_scene_file
from test_hardening import scene_file


def run(path, *flags):
    """(P,3) float64 final positions [m] and the printed summary's lines of `run path --no-progress *flags`, parsed by
    the command's own parser and run in this process."""
    parser = argparse.ArgumentParser()
    add_run_arguments(parser)
    summary, loaded = run_scene_file(path, parser.parse_args(["--no-progress", *map(str, flags)]), quiet=True)
    return loaded.scene.positions(), summary.format().splitlines()


def test_a_perturbed_start_repeats_with_its_seed_and_differs_with_another(tmp_path):
    path = scene_file(tmp_path, frames=3)  # a free 6 x 6 sheet, explicit steps of 1 ms
    plain, plain_again = run(path), run(path)
    one, one_again = (run(path, "--perturb", 1e-7, "--seed", 1) for _ in range(2))
    two = run(path, "--perturb", 1e-7, "--seed", 2)
    assert np.array_equal(plain[0], plain_again[0]) and np.array_equal(one[0], one_again[0])
    assert not np.array_equal(one[0], two[0]) and not np.array_equal(one[0], plain[0])
    assert np.abs(one[0] - two[0]).max() < 1e-5  # a hair apart, not another drape: the distance is in metres
    assert "  start moved by 1e-07 m (seed 1)" in one[1] and "  start moved by 1e-07 m (seed 2)" in two[1]
    assert not any("start moved" in line for line in plain[1])
