"""The house rules of the import graph, read from the source with `ast`: no import circle anywhere, no module
imports another's private name, and the layers stay one-way (clothbase imports none of the other packages;
collision and multilevel never import taichi_cloth)."""
import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("clothbase", "collision", "multilevel", "taichi_cloth")


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
    below = {"clothbase": ("clothbase",), "collision": ("clothbase", "collision"),
             "multilevel": ("clothbase", "collision", "multilevel")}
    crossing = [(m, t) for m, ts in edges.items() for t in ts
                if m.split(".")[0] in below and t.split(".")[0] not in below[m.split(".")[0]]]
    assert crossing == []


def test_the_checker_sees_a_circle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
