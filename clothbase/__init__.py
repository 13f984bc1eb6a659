"""The base layer of taichi-cloth, used by every other package and importing none of them:

  fields   FieldBlock: Taichi fields allocated in one releasable SNode tree per component
  meshes   triangle meshes: topology (edges, interior-edge opposites, connected components), validation with one
           clear message, repair, loading from files (trimesh)
  errors   MeshError, EngineWarning and `warn` (one line, once per message)

The import graph of the engine is one-way: clothbase <- collision, multilevel <- taichi_cloth.
"""
