"""Collision (seed 000 section 2.3, seed 002, seed 004): voxel grid over a body mesh, fuzzy-ordered
continuous particle-triangle tests, sphere and plane colliders, self-collision.

Works on plain Taichi fields and numpy arrays and does not import taichi_cloth, so it can be tested
alone; taichi_cloth.Scene composes it when a scene names [[colliders]]. Nothing is implemented yet
(tracked as the collision issue); importing it builds and compiles nothing.
"""
