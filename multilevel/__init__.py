"""Multilevel 4-8 meshes (Hsiao 2006 section 2.2): the hierarchy, prolongation kernels, and the hierarchy as a
multigrid solver.

  hierarchy   the 4-8 hierarchy of a rectangle (base grid with alternating diagonals, bisection of every
              diamond), parent / diamond / prolongation tables, conformity checks (numpy)
  prolong     the Taichi kernel that refills positions and velocities on a refined level, in place
  multigrid   V-cycles over the levels for the approximate implicit system (Jacobi smoother)
  spring_multigrid  V-cycles over nested 4-8 levels for the implicit (Baraff-Witkin) spring system
  aggregation V-cycles over levels made by aggregating particles, for the same system on any cloth

Works on plain Taichi fields and numpy arrays and does not import taichi_cloth, so it can be tested alone;
taichi_cloth.Scene composes it when a scene's cloth is a multilevel one ([multilevel] in a scene file).
Importing it builds and compiles nothing.
"""
