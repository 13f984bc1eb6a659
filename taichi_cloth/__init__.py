"""taichi-cloth: mass-spring cloth on Taichi kernels.

Life cycle: ClothBuilder -> ClothData -> Model (fields) -> State -> Integrator.step(state, contacts, dt) after the
collision stage (Colliders), composed by a Scene (the only time loop, with the controllers a scene names), recorded by a Recorder. Units are SI throughout
(m, kg, s, N).

    import taichi_cloth as tc
    tc.init("cpu")
    cloth = tc.ClothBuilder.grid((1.0, 1.0), (32, 32), "cotton", center=(0.0, 1.5, 0.0), plane="xz")
    scene = tc.Scene(cloth, dt=1 / 120, pins=[{"near": [[-0.5, 1.5, -0.5], [0.5, 1.5, -0.5]]}])  # two corners
    with tc.Recorder("out/my_cloth.rrd") as rec:
        summary = scene.run(120, recorder=rec)   # 2 s at 60 frames per second
    x = scene.positions()                        # (1024, 3) float64 [m]

A scene file does the same from TOML: `tc.load_scene("demos/scenes/hanging_cloth.toml").scene`.
"""
from .builder import ClothBuilder
from .cloth import ClothData, SpringKind
from .diagnostics import Measurement
from .errors import BlowUpError, MeshError, SceneError, TaichiClothError
from .integrators import INTEGRATORS
from .material import MATERIALS, Material
from .model import Model, State
from .pins import PinSpec
from .runtime import CompileCounter, init
from .scene import Scene
from .scenefile import load_scene
from .summary import RunSummary

__version__ = "0.1.0"


def __getattr__(name: str):
    if name == "Recorder":
        from .recorder import Recorder  # rerun (0.6 s to import): only when something records (PEP 562)

        return Recorder
    raise AttributeError(f"module 'taichi_cloth' has no attribute {name!r}")


__all__ = ["BlowUpError", "ClothBuilder", "ClothData", "CompileCounter", "INTEGRATORS", "MATERIALS", "Material",
           "Measurement", "MeshError", "Model", "PinSpec", "Recorder", "RunSummary", "Scene", "SceneError",
           "SpringKind", "State", "TaichiClothError", "init", "load_scene"]
