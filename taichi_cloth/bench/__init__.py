"""Benchmarks behind `python -m taichi_cloth bench SUITE`: speed and speed/accuracy measurements, printed as
tables and plots, never asserted in tests.

    integrators  ms per step and real-time factor of every integrator (integrators.py)
    collision    collision cost on the mannequin against the voxel size (collision.py)
"""
