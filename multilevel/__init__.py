"""Multilevel 4-8 meshes (seed 000 section 2.2): the hierarchy, settle criteria and prolongation kernels.

Works on plain Taichi fields and numpy arrays and does not import taichi_cloth, so it can be tested
alone; taichi_cloth.Scene composes it when a scene names [multilevel]. Nothing is implemented yet
(tracked as the multilevel issue); importing it builds and compiles nothing.
"""
