"""The dependency direction of DESIGN.md, checked on the source: Blender's Python can import the
engine's io/job/cameras layer (numpy only), the engine never imports bpy, the add-on never
imports the heavy engine dependencies."""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
ENGINE = REPO / "gsgs_engine"
ADDON = REPO / "gsgs_blender"
BLENDER_ONLY = {"bpy", "bmesh", "mathutils", "bpy_extras"}
HEAVY = {"torch", "pycolmap", "diffusers", "cv2"}
# the layer the add-on imports: its module-level imports may be the stdlib, numpy and itself
LIGHT_ROOTS = ["gsgs_engine", "gsgs_engine.io", "gsgs_engine.job", "gsgs_engine.cameras", "gsgs_engine.presets",
               "gsgs_engine.cluster.address"]


def python_files(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*.py") if "__pycache__" not in p.parts)


def module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def module_file(name: str) -> Path | None:
    base = REPO.joinpath(*name.split("."))
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def imports(path: Path, module_level_only: bool) -> list[tuple[int, str]]:
    """(line, absolute module) for each import; module level = what runs on import (not inside
    functions, not under `if TYPE_CHECKING`). `from a import b` lists a and a.b (b may be a module)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    package = module_name(path) if path.name == "__init__.py" else module_name(path).rpartition(".")[0]
    found: list[tuple[int, str]] = []

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if module_level_only and isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                continue
            if module_level_only and isinstance(child, ast.If) and _is_type_checking(child):
                for stmt in child.orelse:
                    visit_stmt(stmt)
                continue
            visit_stmt(child)

    def visit_stmt(node: ast.AST) -> None:
        if isinstance(node, ast.Import):
            found.extend((node.lineno, alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            found.append((node.lineno, target))
            found.extend((node.lineno, f"{target}.{alias.name}") for alias in node.names if alias.name != "*")
        visit(node)

    visit(tree)
    return found


def top(name: str) -> str:
    return name.split(".")[0]


def test_light_layer_does_not_load_heavy_modules():
    code = ("import gsgs_engine.io, gsgs_engine.job, gsgs_engine.cameras, gsgs_engine.io.ply, gsgs_engine.io.exr, "
            "gsgs_engine.presets; "
            "import sys; print('torch' in sys.modules, 'cv2' in sys.modules, 'pycolmap' in sys.modules)")
    env = dict(os.environ, PYTHONPATH=str(REPO))
    done = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == ["False", "False", "False"], done.stdout


def test_light_layer_imports_only_stdlib_numpy_and_itself():
    # Transitively: a light module may import another gsgs_engine module only if that one is light too.
    allowed = set(sys.stdlib_module_names) | {"numpy"}
    seen: set[Path] = set()
    queue = [module_file(name) for name in LIGHT_ROOTS]
    queue += [p for p in python_files(ENGINE / "io")]
    problems = []
    while queue:
        path = queue.pop()
        if path is None or path in seen:
            continue
        seen.add(path)
        for line, name in imports(path, module_level_only=True):
            if top(name) == "gsgs_engine":
                queue.append(module_file(name))  # None for `from pkg import not_a_module`
            elif top(name) not in allowed:
                problems.append(f"{path.relative_to(REPO)}:{line} imports {name} at module level")
    assert len(seen) >= 5  # the check really walked the io/job/cameras files
    assert not problems, "move these imports inside the functions that need them:\n" + "\n".join(problems)


def test_engine_never_imports_blender():
    files = python_files(ENGINE)
    assert len(files) > 5
    problems = [f"{p.relative_to(REPO)}:{line} imports {name}"
                for p in files for line, name in imports(p, module_level_only=False) if top(name) in BLENDER_ONLY]
    assert not problems, "gsgs_engine must run without Blender:\n" + "\n".join(problems)


def test_addon_never_imports_heavy_engine_dependencies():
    # Not even inside functions: heavy work runs in the engine's child process (DESIGN.md).
    problems = [f"{p.relative_to(REPO)}:{line} imports {name}"
                for p in python_files(ADDON) for line, name in imports(p, module_level_only=False) if top(name) in HEAVY]
    assert not problems, "the add-on launches the engine instead of importing these:\n" + "\n".join(problems)


def test_import_scanner_sees_what_it_must(tmp_path, monkeypatch):
    # The checks above are only as good as the scanner: feed it each kind of import once.
    package = tmp_path / "gsgs_engine" / "io"
    package.mkdir(parents=True)
    source = package / "sample.py"
    source.write_text(
        "from __future__ import annotations\n"
        "import numpy as np, torch.nn\n"
        "from typing import TYPE_CHECKING\n"
        "from . import scene\n"
        "from ..render import rasterize\n"
        "try:\n    import cv2\nexcept ImportError:\n    cv2 = None\n"
        "if TYPE_CHECKING:\n    import pycolmap\n"
        "class A:\n    import bpy\n"
        "def f():\n    import diffusers\n"
        "'import mathutils'  # a string, not an import\n")
    monkeypatch.setattr(sys.modules[__name__], "REPO", tmp_path)
    module_level = {name for _, name in imports(source, module_level_only=True)}
    assert {"numpy", "torch.nn", "cv2", "bpy", "gsgs_engine.io", "gsgs_engine.io.scene",
            "gsgs_engine.render", "gsgs_engine.render.rasterize"} <= module_level
    assert not {"pycolmap", "diffusers", "mathutils"} & module_level
    everywhere = {name for _, name in imports(source, module_level_only=False)}
    assert {"pycolmap", "diffusers"} <= everywhere and "mathutils" not in everywhere
