"""Multilevel 4-8 meshes (Hsiao 2006 section 2.2): the hierarchy and its prolongation kernels.

  hierarchy   the 4-8 hierarchy of a rectangle (base grid with alternating diagonals, bisection of every
              diamond), parent / diamond / prolongation tables, conformity checks (numpy)
  prolong     the Taichi kernel that refills positions and velocities on a refined level, in place
(The implicit step's V-cycles over these levels are taichi_cloth.linear's.)

Works on plain Taichi fields and numpy arrays and does not import taichi_cloth, so it can be tested alone;
taichi_cloth.Scene composes it when a scene's cloth is a multilevel one ([multilevel] in a scene file).
Importing it builds and compiles nothing.
"""
