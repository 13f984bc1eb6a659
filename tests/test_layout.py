"""The house rules of the import graph, read from the source with `ast`: no import circle anywhere, no module
imports another's private name, the layers stay one-way (LAYERS), and imports sit at the top of a module unless
the lazy import is the point (LAZY)."""
import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("clothbase", "collision", "multilevel", "taichi_cloth", "benchmarks")

#: the layers, lowest first: a module may import its own layer and the ones below, never one above
PACKAGE_LAYERS = (
    ("clothbase",),                       # field blocks, meshes, errors: imports no other package
    ("collision", "multilevel"),          # collision and 4-8 hierarchies on plain fields: never the engine
    ("taichi_cloth",),                    # the engine
    ("benchmarks",),                      # measures the engine; the engine never imports it
)
#: the same inside the engine; a module no layer names (e.g. taichi_cloth.model, .forces, .control) is free
ENGINE_LAYERS = (
    # the steps and their solvers know a model, a state, forces and contacts, never how a scene is put together
    ("taichi_cloth.integrators", "taichi_cloth.linear"),
    ("taichi_cloth.body",),               # bodies: landmarks, girths, blend shapes; no garment
    ("taichi_cloth.garment",),            # garments are made on bodies
    ("taichi_cloth.assembly", "taichi_cloth.scene"),  # a scene composes the features
    ("taichi_cloth.scenefile", "taichi_cloth.cli", "taichi_cloth.__main__"),  # files and the command line
)

#: what a function may import lazily: modules that take long to import (or are optional extras) and serve one
#: rarely used path; everything else is imported at the top of the module
LAZY = ("rerun", "playwright", "warp", "pxr", "ray", "matplotlib", "trimesh", "meshio", "ezdxf", "scipy", "tqdm",
        "PIL",                          # matplotlib's image library: the still pictures' PNG writer
        "taichi_cloth.recorder",        # rerun
        "taichi_cloth.garment.local",   # scipy.spatial, for a garment refined locally
        "taichi_cloth.garment.dxf",     # ezdxf
        "taichi_cloth.body",            # fit_body: scipy, for a [body] table
        "starlette", "uvicorn", "multipart",  # the pattern studio's server: the `studio` extra
        "taichi_cloth.studio.server",   # starlette
        "pyarrow",                      # the batch's results table
        "taichi_cloth.batch.cluster")   # ray: the `cluster` extra


def modules() -> dict[str, Path]:
    out = {}
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = path
    return out


def imports(mods: dict[str, Path]):
    """(module -> set of engine modules it imports anywhere in its body, [(module, imported private name)])."""
    edges, private = {m: set() for m in mods}, []
    for name, path in mods.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                    base = ".".join(up + ([node.module] if node.module else []))
                for alias in node.names:
                    target = f"{base}.{alias.name}" if f"{base}.{alias.name}" in mods else base
                    if target in mods and target != name:
                        edges[name].add(target)
                    if alias.name.startswith("_") and not alias.name.startswith("__"):
                        private.append((name, f"{base}.{alias.name}"))
            elif isinstance(node, ast.Import):
                edges[name].update(a.name for a in node.names if a.name in mods and a.name != name)
    return edges, private


def layer(module: str, layers) -> int:
    """The index in `layers` of the layer naming `module` or a package above it (-1: none)."""
    for k, names in enumerate(layers):
        if any(module == name or module.startswith(name + ".") for name in names):
            return k
    return -1


def upward(edges: dict[str, set]) -> list[tuple[str, str]]:
    """The imports from a lower layer to a higher one: between packages, and inside the engine."""
    out = []
    for m, ts in edges.items():
        for t in ts:
            lo, hi = layer(m, PACKAGE_LAYERS), layer(t, PACKAGE_LAYERS)
            if lo == hi:
                lo, hi = layer(m, ENGINE_LAYERS), layer(t, ENGINE_LAYERS)
            if hi > lo >= 0:
                out.append((m, t))
    return sorted(out)


def local_imports(mods: dict[str, Path]) -> list[str]:
    """'module.function: target' for every import inside a function body that LAZY does not allow."""
    out = []
    for name, path in mods.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for fn in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            where = f"{name}.{fn.name}"
            for node in ast.walk(fn):
                if isinstance(node, ast.ImportFrom):
                    base = node.module or ""
                    if node.level:
                        up = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                        base = ".".join(up + ([node.module] if node.module else []))
                    targets = [base]
                elif isinstance(node, ast.Import):
                    targets = [a.name for a in node.names]
                else:
                    continue
                for target in targets:
                    lazy = any(target == m or target.startswith(m + ".") for m in LAZY)
                    if not lazy:
                        out.append(f"{where}: {target}")
    return out


def cycles(edges: dict[str, set]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in edges:
        if v not in index:
            visit(v)
    return out


def test_the_import_graph_has_no_circle_no_private_import_and_one_way_layers():
    mods = modules()
    assert len(mods) > 60  # the walk found the engine
    edges, private = imports(mods)
    assert cycles(edges) == []
    assert private == []
    assert upward(edges) == []


def test_collision_and_multilevel_stay_apart():
    """Two packages of one layer: neither imports the other."""
    edges, _ = imports(modules())
    assert [(m, t) for m, ts in edges.items() for t in ts
            if {m.split(".")[0], t.split(".")[0]} == {"collision", "multilevel"}] == []


def test_the_checker_sees_an_upward_import():
    """body/ importing garment/ (placement's Body, as GirthGauge once did) and an integrator importing the scene
    are both caught; the way down is not."""
    edges = {"taichi_cloth.body.girth": {"taichi_cloth.garment.placement"},
             "taichi_cloth.integrators.implicit": {"taichi_cloth.scene"},
             "collision.body": {"taichi_cloth.model"},
             "taichi_cloth.garment.garment": {"taichi_cloth.body.landmarks", "taichi_cloth.model"},
             "taichi_cloth.scene": {"taichi_cloth.integrators.base", "clothbase.meshes"}}
    assert upward(edges) == [("collision.body", "taichi_cloth.model"),
                             ("taichi_cloth.body.girth", "taichi_cloth.garment.placement"),
                             ("taichi_cloth.integrators.implicit", "taichi_cloth.scene")]


def test_imports_sit_at_the_top_unless_lazy_is_the_point():
    assert local_imports(modules()) == []


def test_the_checker_sees_a_circle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
