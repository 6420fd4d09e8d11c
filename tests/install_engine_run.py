"""Run by tests/test_blender_install.py in its own process (the real bpy module, a fresh HOME):

    python install_engine_run.py ZIP PHOTOS JOBS WORKING_PYTHON WORKING_ENGINE_ROOT TORCH_BUILD

Installs the extension zip as "Install from Disk" does, sets Engine Python to a working engine, then
1. Install Engine with an unreachable Package Index (must fail, changing nothing),
2. Install Engine cancelled during its torch step (must change nothing),
3. Install Engine from the package index (torch: TORCH_BUILD, "cpu" where PyTorch's CPU index can be
   reached, else "index", torch as pip's configured index and find-links serve it), timed, its disk
   use measured,
4. Check Engine, and photos -> cameras -> train (30 steps) -> import through the add-on's operators
   with the engine it installed,
5. Reinstall Engine, then Uninstall Engine.
Prints `RESULT <json>` last; the test asserts on it. Not collected by pytest (no test_ prefix).
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import bpy

ZIP, PHOTOS, JOBS, WORKING_PYTHON, WORKING_ROOT, TORCH_BUILD = sys.argv[1:7]
ADDON = "bl_ext.user_default.gsgs"
result: dict = {}


def du_mb(path: Path) -> float:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file() and not p.is_symlink()) / 1e6


def check() -> dict:
    """Check Engine through its operator: did it pass, and its report."""
    try:
        ok = bpy.ops.gsgs.check_engine() == {"FINISHED"}
    except RuntimeError:
        ok = False
    return {"ok": ok, "report": prefs.engine_report, "python": prefs.python_path, "root": prefs.engine_root}


def leftovers() -> list[str]:
    root = engine_install.engines_dir()
    return sorted(p.name for p in root.glob("engine-*") if p.is_dir()) if root.is_dir() else []


assert bpy.ops.extensions.package_install_files(filepath=ZIP, repo="user_default", enable_on_install=True) == {"FINISHED"}
prefs = bpy.context.preferences.addons[ADDON].preferences
engine_install = sys.modules[f"{ADDON}.engine_install"]
ops_engine = sys.modules[f"{ADDON}.ops_engine"]
prefs.python_path, prefs.engine_root, prefs.jobs_dir = WORKING_PYTHON, WORKING_ROOT, JOBS
prefs.torch_build = TORCH_BUILD
result["engines_dir"] = str(engine_install.engines_dir())
result["before"] = check()

# 1. an unreachable package index
prefs.install_index_url = "http://127.0.0.1:9/simple"
t0 = time.monotonic()
try:
    bpy.ops.gsgs.install_engine()
    result["bad_index"] = {"raised": None}
except RuntimeError as exc:
    result["bad_index"] = {"raised": str(exc)}
result["bad_index"].update(seconds=round(time.monotonic() - t0, 1), message=engine_install.current().message,
                           after=check(), leftovers=leftovers())
prefs.install_index_url = ""

# 2. a cancel in the middle of the torch step
run = engine_install.start(prefs, on_finish=ops_engine._installed(""), use_timer=False)
t0 = time.monotonic()
while not run.finished and run.last_event.get("step") != "torch" and time.monotonic() - t0 < 600:
    run.poll()
    time.sleep(0.2)
time.sleep(3.0)  # pip is working on torch now
result["cancel"] = {"step_at_cancel": run.last_event.get("step"), "env_existed": run.env.exists()}
assert bpy.ops.gsgs.cancel_engine_install() == {"FINISHED"}
run.wait(echo=False)
engine_install.finish(run)
result["cancel"].update(state=run.state, message=run.message, env_exists=run.env.exists(), after=check(),
                        leftovers=leftovers(), seconds_to_stop=round(time.monotonic() - run.cancel_at, 1))

# 3. the real install, timed. Check Engine on the working engine above compiled the kernel into this
# fresh HOME's cache (for the same torch and Python): delete it, so the installer's build is a real one.
shutil.rmtree(Path.home() / ".cache" / "gsgs" / "torch_extensions", ignore_errors=True)
t0 = time.monotonic()
assert bpy.ops.gsgs.install_engine() == {"FINISHED"}
seconds = time.monotonic() - t0
run = engine_install.current()
cache = Path.home() / ".cache" / "gsgs"  # the compiled kernel and the LPIPS weights (HOME is fresh)
result["install"] = {"seconds": round(seconds, 1), "message": run.message, "final": run.final,
                     "env": str(run.env), "env_mb": round(du_mb(run.env), 1),
                     "cache_mb": round(du_mb(cache), 1) if cache.is_dir() else 0.0,
                     "kernel_built": any(cache.glob("torch_extensions/*/*.so")),
                     "lpips": sorted(p.name for p in cache.glob("lpips/*.safetensors")), "leftovers": leftovers()}
result["after_install"] = check()
gsgs_cli = run.env / "bin" / "gsgs"
result["cli"] = [subprocess.run(argv, capture_output=True, text=True, timeout=300).returncode
                 for argv in ([str(gsgs_cli), "--help"], [prefs.python_path, "-m", "gsgs_engine", "--help"])]

# 4. photos -> cameras -> train -> import with the installed engine
scene = bpy.context.scene
scene.gsgs.photos_dir = PHOTOS
scene.gsgs.max_image_size = 480
result["import_photos"] = sorted(bpy.ops.gsgs.import_photos())
result["cameras"] = len(sys.modules[f"{ADDON}.pseudo_paths"].training_camera_objects(scene))
scene.gsgs.iterations = 30
scene.gsgs.resolution_scale = 0.25
scene.gsgs.generator = "none"
result["train"] = sorted(bpy.ops.gsgs.train())
obj = scene.gsgs.result_object
result["splats"] = int(obj["gsgs_count"]) if obj is not None else 0
result["vertices"] = len(obj.data.vertices) if obj is not None else 0
logs = {name: (Path(bpy.path.abspath(getattr(scene.gsgs, name))) / "log.txt").read_text()
        for name in ("sfm_job", "train_job")}
result["job_pythons"] = {name: next((ln.split()[3] for ln in text.splitlines() if ln.startswith("== gsgs: starting")), "")
                         for name, text in logs.items()}
metrics = Path(bpy.path.abspath(scene.gsgs.train_job)) / "result" / "metrics.json"
result["metrics"] = json.loads(metrics.read_text()) if metrics.is_file() else None

# 5. Reinstall (a second install replaces the first only once it works), then Uninstall
first = run.env
t0 = time.monotonic()
assert bpy.ops.gsgs.install_engine() == {"FINISHED"}
second = engine_install.current().env
result["reinstall"] = {"seconds": round(time.monotonic() - t0, 1), "first_exists": first.exists(),
                       "second": str(second), "python": prefs.python_path, "leftovers": leftovers()}
assert bpy.ops.gsgs.uninstall_engine() == {"FINISHED"}
result["uninstall"] = {"leftovers": leftovers(), "python": prefs.python_path, "root": prefs.engine_root,
                       "second_exists": second.exists()}
print("RESULT " + json.dumps(result, default=str))
