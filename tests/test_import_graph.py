"""The import graph inside gsgs_engine and gsgs_blender: no cycles (function-level imports count), and
the engine's layers import only downwards (DESIGN.md: commands / bench above the orchestration,
the orchestration above the effect plan, the effect plan above training, training above the priors,
the renderer and io). The trainer names no technique."""

from __future__ import annotations

import test_layering
from test_layering import imports, module_name, python_files

# A module of a layer may import modules of the same or lower layers only (prefix match; the longest wins).
ENGINE_LAYERS = {
    "gsgs_engine.cli": 6, "gsgs_engine.commands": 6, "gsgs_engine.__main__": 6,
    "gsgs_engine.bench": 5,
    "gsgs_engine.reconstruct": 4,
    "gsgs_engine.effect_plan": 3,
    "gsgs_engine.train": 2,
    "gsgs_engine": 1,  # priors, render, io, cameras, gaussians, sfm, metrics, ... and the package itself
}


def module_graph(packages: list[str]) -> dict[str, set[str]]:
    """module -> the modules of `packages` it imports anywhere in its source (module or function level)."""
    files = {module_name(p): p for pkg in packages for p in python_files(test_layering.REPO / pkg)}
    graph: dict[str, set[str]] = {}
    for mod, path in files.items():
        edges = set()
        for _, name in imports(path, module_level_only=False):
            # `from pkg import name` lists pkg and pkg.name: keep the ones that are modules of ours
            if name in files and name != mod and not mod.startswith(name + "."):
                edges.add(name)  # importing one's own parent package is no edge back into the package's modules
        graph[mod] = edges
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (iterative Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    found: list[list[str]] = []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                parent = work[-1][0]
                low[parent] = min(low[parent], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def layer(module: str) -> int:
    best = max((prefix for prefix in ENGINE_LAYERS if module == prefix or module.startswith(prefix + ".")), key=len)
    return ENGINE_LAYERS[best]


def test_no_import_cycles_in_either_package():
    graph = module_graph(["gsgs_engine", "gsgs_blender"])
    assert len(graph) > 60  # the scan really saw both packages
    found = cycles(graph)
    assert not found, "import cycles (a module its importer needs belongs in a shared module):\n" + "\n".join(
        " <-> ".join(c) for c in found)


def test_engine_layers_import_only_downwards():
    graph = module_graph(["gsgs_engine"])
    upward = [f"{mod} (layer {layer(mod)}) imports {dep} (layer {layer(dep)})"
              for mod, deps in sorted(graph.items()) for dep in sorted(deps) if layer(dep) > layer(mod)]
    assert not upward, "\n".join(upward)


def test_trainer_names_no_technique_and_no_orchestration():
    graph = module_graph(["gsgs_engine"])
    deps = graph["gsgs_engine.train.trainer"]
    named = sorted(d for d in deps if d.startswith("gsgs_engine.train.techniques") or d in (
        "gsgs_engine.effect_plan", "gsgs_engine.reconstruct", "gsgs_engine.priors.config"))
    assert not named, f"train/trainer.py imports {named}"


def test_the_checks_see_a_cycle_and_an_upward_import(tmp_path, monkeypatch):
    # The checks are only as good as the graph: a function-level cycle and an upward import must show.
    pkg = tmp_path / "gsgs_engine"
    (pkg / "train").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "train" / "__init__.py").write_text("")
    (pkg / "train" / "a.py").write_text("from gsgs_engine.train import b\n")
    (pkg / "train" / "b.py").write_text("def f():\n    from gsgs_engine.train.a import x\n")
    (pkg / "train" / "c.py").write_text("def g():\n    import gsgs_engine.reconstruct\n")
    (pkg / "reconstruct.py").write_text("from gsgs_engine.train import c\n")
    monkeypatch.setattr(test_layering, "REPO", tmp_path)
    graph = module_graph(["gsgs_engine"])
    assert sorted(cycles(graph)) == [["gsgs_engine.reconstruct", "gsgs_engine.train.c"],
                                     ["gsgs_engine.train.a", "gsgs_engine.train.b"]]
    assert layer("gsgs_engine.train.c") < layer("gsgs_engine.reconstruct")
    assert "gsgs_engine.reconstruct" in graph["gsgs_engine.train.c"]
