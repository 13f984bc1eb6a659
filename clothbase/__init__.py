"""The base layer of taichi-cloth, used by every other package and importing none of them:

  fields   FieldBlock: Taichi fields allocated in one releasable SNode tree per component
  meshes   triangle meshes: topology (edges, interior-edge opposites, connected components), validation with one
           clear message, repair, loading from files (trimesh)
  errors   MeshError, EngineWarning and `warn` (one line, once per message)
  fixedpoint  to_fixed / from_fixed: sums a parallel scatter adds in any order and gets the same result

The import graph of the engine is one-way: clothbase <- collision, multilevel <- taichi_cloth.
"""
