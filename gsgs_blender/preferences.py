"""Add-on preferences (engine interpreter, model folders, device) and per-scene settings.

The .blend keeps only settings and job folder paths; images, progress and results stay in
the job folders, so a file opened on another machine points at (and can re-run) its jobs.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import tempfile
from pathlib import Path

import bpy
from bpy.props import (BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty,
                       StringProperty)

from gsgs_engine import __version__ as ADDON_VERSION
from gsgs_engine import presets

from . import engine_install, node_groups, splat_import
from .node_groups import DEFAULT_SIZE as DEFAULT_SPLAT_SIZE
from .render_setup import COLOUR_ITEMS, DEFAULT_COLOUR_MODE

# The checkout this add-on runs from, when it is one (gsgs_blender/ next to gsgs_engine/).
_CHECKOUT = Path(__file__).resolve().parents[1]
ADDON_ID = __package__


def default_python() -> str:
    venv = _CHECKOUT / ".venv" / ("Scripts/python.exe" if os.name == "nt" else "bin/python")
    return str(venv) if venv.exists() else "python3"


def default_engine_root() -> str:
    return str(_CHECKOUT) if (_CHECKOUT / "gsgs_engine" / "__main__.py").is_file() else ""


RUN_ON = [("local", "This Computer", "jobs run in a background process here"),
          ("ray", "Ray Cluster", "jobs run on a Ray cluster; their files come back into the job folders")]
DEVICES = [("auto", "Auto", "CUDA when available, else CPU"),
           ("cpu", "CPU", "always the CPU (slow, works everywhere)"),
           ("cuda", "CUDA", "an NVIDIA GPU; the job fails clearly when none is present")]


class GSGS_AddonPreferences(engine_install.InstallPreferences, bpy.types.AddonPreferences):
    bl_idname = ADDON_ID

    python_path: StringProperty(
        name="Engine Python", subtype="FILE_PATH", default=default_python(),
        description="Python interpreter with torch, pycolmap and OpenCV that runs the engine jobs")
    engine_root: StringProperty(
        name="Engine Source", subtype="DIR_PATH", default=default_engine_root(),
        description="Folder holding gsgs_engine/ (a source checkout), put first on the engine's PYTHONPATH; "
                    "leave empty when the engine is installed in that Python")
    jobs_dir: StringProperty(
        name="Jobs Folder", subtype="DIR_PATH", default="",
        description="Where new job folders go; empty: next to the saved .blend (gsgs_jobs/), else the temp folder")
    diffusion_dir: StringProperty(
        name="Diffusion Model", subtype="DIR_PATH", default="",
        description="Local Stable Diffusion 1.5-class model folder (diffusers layout); empty: weights-free prior")
    depth_adapter_dir: StringProperty(
        name="Depth Adapter", subtype="DIR_PATH", default="",
        description="Local depth T2I-Adapter folder (diffusers layout)")
    depth_estimator_dir: StringProperty(
        name="Depth Estimator", subtype="DIR_PATH", default="",
        description="Local DPT depth estimator folder (transformers layout)")
    device: EnumProperty(name="Device", items=DEVICES, default="auto",
                         description="Where the engine trains")
    run_on: EnumProperty(name="Run Jobs On", items=RUN_ON, default="local",
                         description="Where SfM and training jobs run (docs/cluster.md)")
    ray_address: StringProperty(
        name="Ray Address", default="127.0.0.1:6380",
        description="HOST:PORT of the Ray head (`ray start --head --port 6380`), or ray://HOST:10001; "
                    "any host but this one needs the token")
    ray_token: StringProperty(
        name="Ray Token", subtype="PASSWORD", default="",
        description="The cluster's authentication token (`ray get-auth-token`), sent as RAY_AUTH_TOKEN")
    ray_cpus: IntProperty(name="CPUs per Job", default=1, min=1, soft_max=64,
                          description="CPUs a job asks the cluster for (the engine uses as many threads)")
    engine_report: StringProperty(name="Engine Report", default="",
                                  description="Result of the last Check Engine")

    def draw(self, context):
        layout = self.layout
        col = layout.column()
        col.prop(self, "python_path")
        col.prop(self, "engine_root")
        col.prop(self, "jobs_dir")
        col.prop(self, "device")
        draw_run_on(self, layout)
        box = layout.box()
        box.label(text="Model folders (local; nothing is downloaded)")
        box.prop(self, "diffusion_dir")
        box.prop(self, "depth_adapter_dir")
        box.prop(self, "depth_estimator_dir")
        row = layout.row()
        row.operator("gsgs.check_engine", icon="CONSOLE")
        for line in self.engine_report.split("\n"):
            if line:
                layout.label(text=line)
        self.draw_install(layout)

    def draw_install(self, layout) -> None:
        """Install Engine / Reinstall / Uninstall, its settings and progress (engine_install)."""
        engine_install.draw_preferences(self, layout)


def draw_run_on(prefs, layout) -> None:
    box = layout.box()
    box.prop(prefs, "run_on")
    if prefs.run_on == "ray":
        box.prop(prefs, "ray_address")
        box.prop(prefs, "ray_token")
        box.prop(prefs, "ray_cpus")
        box.label(text="Workers need the same gsgs version; results come back into the job folders")


class _Defaults:
    """Preferences when the add-on was registered without the add-on system (bpy module tests)."""

    python_path = default_python()
    engine_root = default_engine_root()
    install_python = install_index_url = torch_index_url = ""
    torch_build = "auto"
    jobs_dir = ""
    diffusion_dir = depth_adapter_dir = depth_estimator_dir = ""
    device = "auto"
    engine_report = ""
    run_on = "local"
    ray_address = "127.0.0.1:6380"
    ray_token = ""
    ray_cpus = 1


_FALLBACK = _Defaults()


def get_prefs(context=None):
    context = context or bpy.context
    addon = context.preferences.addons.get(ADDON_ID)
    return addon.preferences if addon is not None and addon.preferences is not None else _FALLBACK


def prior_settings(prefs, generator: str, rounds: int) -> dict:
    """job.json settings of the generative prior (the engine's PriorConfig field names)."""
    if generator == "none":
        return {"prior": "none"}
    d = {"rounds": int(rounds), "device": prefs.device}
    if prefs.diffusion_dir:
        d["diffusion_model"] = bpy.path.abspath(prefs.diffusion_dir)
    if prefs.depth_adapter_dir:
        d["depth_adapter"] = bpy.path.abspath(prefs.depth_adapter_dir)
    if prefs.depth_estimator_dir:
        d["depth_source"] = bpy.path.abspath(prefs.depth_estimator_dir)
    return {"prior": generator, "prior_settings": d}


def jobs_root(context=None) -> Path:
    prefs = get_prefs(context)
    if prefs.jobs_dir:
        return Path(bpy.path.abspath(prefs.jobs_dir))
    if bpy.data.filepath:
        return Path(bpy.path.abspath("//gsgs_jobs"))
    return Path(tempfile.gettempdir()) / "gsgs_jobs"


# What the engine interpreter reports about itself; printed as one JSON line.
CHECK_SCRIPT = r"""
import json, sys
info = {"python": sys.version.split()[0]}
for name in ("numpy", "torch", "pycolmap", "cv2", "diffusers"):
    try:
        mod = __import__(name)
        info[name] = getattr(mod, "__version__", "?")
    except Exception as exc:
        info[name] = None
try:
    torch = __import__("torch")  # in the engine's interpreter, never in Blender's
    info["cuda"] = torch.cuda.is_available()
    info["cuda_device"] = torch.cuda.get_device_name(0) if info["cuda"] else None
except Exception:
    info["cuda"] = False
try:
    import gsgs_engine
    info["gsgs_engine"] = gsgs_engine.__version__
    try:
        from gsgs_engine.render import available_backends
        info["backends"] = [name for name, (ok, _) in available_backends().items() if ok]
    except Exception:
        info["backends"] = None
except Exception as exc:
    info["gsgs_engine"] = None
    info["engine_error"] = f"{type(exc).__name__}: {exc}"
print("GSGS_CHECK " + json.dumps(info))
"""


def check_engine(python: str, engine_root: str = "", timeout: float = 120.0) -> tuple[bool, str]:
    """Run CHECK_SCRIPT in the engine interpreter (argument list, no shell) -> (usable, report)."""
    from .job_runner import engine_env

    try:
        proc = subprocess.run([python, "-c", CHECK_SCRIPT], capture_output=True, text=True, timeout=timeout,
                              env=engine_env(engine_root or None), cwd=engine_root or None)
    except FileNotFoundError:
        return False, (f"{python}: no such interpreter; press Install Engine below, or set Engine Python to a "
                       "Python 3.11 to 3.13 with the engine installed")
    except subprocess.TimeoutExpired:
        return False, f"{python}: no answer within {timeout:.0f} s"
    line = next((ln for ln in proc.stdout.splitlines() if ln.startswith("GSGS_CHECK ")), None)
    if line is None:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no output"]
        return False, f"{python} failed (exit {proc.returncode}): {tail[0]}"
    info = json.loads(line[len("GSGS_CHECK "):])
    missing = [k for k in ("numpy", "torch", "pycolmap", "cv2", "gsgs_engine") if not info.get(k)]
    lines = [f"Python {info['python']}  numpy {info.get('numpy')}  torch {info.get('torch')}",
             f"pycolmap {info.get('pycolmap')}  OpenCV {info.get('cv2')}  diffusers {info.get('diffusers')}",
             f"CUDA: {info.get('cuda_device') or 'not available'}"
             + (f"  backends: {', '.join(info['backends'])}" if info.get("backends") else "")]
    if missing:
        lines.append("missing: " + ", ".join(missing) + (f" ({info['engine_error']})" if info.get("engine_error") else ""))
    mismatch = version_mismatch(info.get("gsgs_engine"), python, engine_root)
    if mismatch:
        lines.append(mismatch)
    return not missing and not mismatch, "\n".join(lines)


def version_mismatch(engine_version: str | None, python: str, engine_root: str = "") -> str:
    """The engine in `python` must be the add-on's version (the job folder protocol is theirs together)."""
    if not engine_version or engine_version == ADDON_VERSION:
        return ""
    where = f"Engine Source {engine_root}" if engine_root else python
    fix = "update that checkout" if engine_root else "press Reinstall Engine below"
    return (f"version mismatch: the engine in {where} is {engine_version}, this add-on is {ADDON_VERSION}; "
            f"{fix} so they match")


class GSGS_OT_check_engine(bpy.types.Operator):
    bl_idname = "gsgs.check_engine"
    bl_label = "Check Engine"
    bl_description = "Run the engine Python once and report torch, pycolmap and OpenCV versions and backends"

    def execute(self, context):
        prefs = get_prefs(context)
        ok, report = check_engine(bpy.path.abspath(prefs.python_path), bpy.path.abspath(prefs.engine_root))
        prefs.engine_report = report
        self.report({"INFO"} if ok else {"ERROR"}, report.replace("\n", "; "))
        return {"FINISHED"} if ok else {"CANCELLED"}


ORIENTATIONS = [("LOOK_AT", "Look at Centre", "every pseudo camera looks at the scene centre"),
                ("SLERP", "Interpolate", "orientation slerped between the two nearest training cameras")]
# The engine's prior choices (gsgs_engine.priors.config.PRIOR_CHOICES), sent as settings["prior"].
GENERATORS = [("auto", "Auto", "diffusion when the model folders are set, else the weights-free warp prior"),
              ("diffusion", "Diffusion", "depth-conditioned latent diffusion with LoRA adaptation (needs models)"),
              ("warp", "Warp + Inpaint", "weights-free: warp training photos with rendered depth, inpaint holes"),
              ("depth", "Depth Only", "no generated views; only the depth regulariser (eq. 8-10)"),
              ("none", "None (plain 3DGS)", "train on the photos alone: the sparse-view baseline")]


def _preset_cost(name: str) -> str:
    """A preset's measured cost as gsgs_engine.presets' docstring states it (read at runtime, never copied):
    a line `  NAME  cost...`, else each bullet's `ITERS it ...` figures with the bullet's data set."""
    doc = presets.__doc__ or ""
    for line in doc.splitlines():
        words = line.split(None, 1)
        if line.startswith("  ") and len(words) == 2 and words[0] == name:
            return words[1].strip()
    found = []
    for bullet in re.split(r"\n\s+- ", doc)[1:]:
        bullet = " ".join(bullet.split())
        label = re.sub(r"\s*\(.*?\)", "", bullet.split(":")[0])
        figures = [f.strip() for f in re.findall(rf"\b{presets.PRESETS[name]['iters']} it\b[^,;()]*?\d s\b", bullet)]
        if figures:
            found.append(f"{label}: {', '.join(figures)}")
    return "; ".join(found) or "not measured yet (docs/accuracy_*.md)"


def _preset_item(name: str) -> tuple[str, str, str]:
    p = presets.PRESETS[name]
    cap = f"at most {p['max_side']} px" if p["max_side"] else "no size cap"
    text = (f"{p['iters']} iterations, resolution {p['resolution_scale']} ({cap}), prior {p['prior']}, "
            f"{p['pseudo_views']} pseudo views, {p['rounds']} rounds, SH {p['sh_degree']}, backend {p['backend']}. "
            f"Measured: {_preset_cost(name)}")
    return (name, name.title(), text)


# `gsgs train --preset`: the values come from the engine's table (torch-free), so the two never disagree.
PRESETS = [("custom", "Custom", "Keep the training fields below as you set them")] + [
    _preset_item(name) for name in presets.PRESET_NAMES]
DEFAULT_PRESET = "balanced"  # the engine's own default schedule (gsgs train without flags)
_DEFAULTS = presets.PRESETS[DEFAULT_PRESET]
# panel field -> preset key; pseudo views, SH degree and backend have no field: the job's "preset" sets them
PRESET_FIELDS = {"iterations": "iters", "resolution_scale": "resolution_scale", "max_side": "max_side",
                 "generator": "prior", "rounds": "rounds"}
_applying_preset = False


def preset_matches(settings, name: str) -> bool:
    p = presets.PRESETS[name]
    return all(abs(getattr(settings, f) - p[k]) < 1e-6 if f == "resolution_scale" else getattr(settings, f) == p[k]
               for f, k in PRESET_FIELDS.items())


def _apply_preset(self, context) -> None:
    """Choosing a preset sets the training fields to its values; Custom leaves them alone."""
    global _applying_preset
    if self.preset == "custom":
        return
    p = presets.PRESETS[self.preset]
    _applying_preset = True
    try:
        for field_name, key in PRESET_FIELDS.items():
            setattr(self, field_name, p[key])
    finally:
        _applying_preset = False


def _training_field_edited(self, context) -> None:
    """Editing a training field away from the preset's value makes the preset Custom again."""
    if _applying_preset or self.preset == "custom":
        return
    if not preset_matches(self, self.preset):
        self.preset = "custom"


def _update_display(self, context) -> None:
    """Push the display settings into the result object's geometry-nodes modifier."""
    obj = self.result_object
    mod = obj.modifiers.get("GS-GS Splats") if obj is not None else None
    if mod is None or mod.node_group is None:
        return
    count = len(obj.data.vertices) if obj.type == "MESH" else 0
    node_groups.set_modifier_input(mod, "Display Ratio", splat_import.display_ratio_for(count, self.max_display))
    node_groups.set_modifier_input(mod, "Size", float(self.splat_size))
    obj.update_tag()


class GSGS_SceneSettings(bpy.types.PropertyGroup):
    photos_dir: StringProperty(name="Photos", subtype="DIR_PATH", options={"PATH_SUPPORTS_BLEND_RELATIVE"},
                               description="Folder of photos to reconstruct (JPEG, PNG, TIFF, WebP, HEIC; "
                                           "turned upright by their EXIF orientation)")
    max_image_size: IntProperty(name="Max Image Size", default=1600, min=64, max=8192,
                                description="Larger photos are downscaled once to this longer side; SfM, "
                                            "the camera backgrounds and training use those copies")
    video_dir: StringProperty(name="Video", subtype="DIR_PATH", options={"PATH_SUPPORTS_BLEND_RELATIVE"},
                              description="Folder of a synchronised multi-view video with calibrated cameras (CMU "
                                          "Panoptic, Neural 3D Video, NeRF JSON with times)")
    video_train_cameras: IntProperty(name="Training Cameras", default=9, min=0, max=10_000,
                                     description="Train on this many of the video's cameras, spread evenly (the "
                                                 "sparse protocol: 3, 6 or 9; 0: all); the held-out ones are the "
                                                 "capture's test cameras")
    video_frames: StringProperty(name="Frames", default="",
                                 description="Frame ids to train on, e.g. 0-29 or 0,10,20 (empty: every frame)")
    video_source: StringProperty(name="Imported Video", subtype="DIR_PATH",
                                 description="The multi-view video the training cameras came from (empty: photos); "
                                             "Train names it in the job instead of the cameras' photos")
    sfm_job: StringProperty(name="SfM Job", subtype="DIR_PATH", options={"PATH_SUPPORTS_BLEND_RELATIVE"},
                            description="Job folder of the camera solve")
    camera_collection: PointerProperty(name="Cameras", type=bpy.types.Collection,
                                       description="Collection whose camera objects are the training views")
    points_object: PointerProperty(name="Sparse Points", type=bpy.types.Object,
                                   description="Sparse points of the camera solve. Training triangulates its own "
                                               "points from the photos and uses these only when that gives too "
                                               "few; they also show the scene's extent for drawing a path")
    pseudo_curve: PointerProperty(name="Path", type=bpy.types.Object,
                                  description="Curve the pseudo cameras are sampled along")
    pseudo_count: IntProperty(name="Pseudo Views", default=16, min=1, max=512,
                              description="How many pseudo poses to sample along the path. The engine adds "
                                          "these to its own automatic pseudo views (as many as the job's pseudo "
                                          "view setting, 16 unless a preset says otherwise), so 16 here gives 32 "
                                          "per round. Path poses are used only when a Generator is on")
    pseudo_orientation: EnumProperty(name="Orientation", items=ORIENTATIONS, default="LOOK_AT")
    pseudo_poses: StringProperty(name="Pseudo Poses", default="[]",
                                 description="Sampled pseudo poses as JSON (Camera.to_dict list)")
    show_frusta: BoolProperty(name="Show Frusta", default=True, description="Draw the pseudo cameras in the viewport")
    preset: EnumProperty(name="Preset", items=PRESETS, default=DEFAULT_PRESET, update=_apply_preset,
                         description="Settings from the measured accuracy/time front (`gsgs train --preset`); "
                                     "editing a field below makes it Custom")
    iterations: IntProperty(name="Iterations", default=_DEFAULTS["iters"], min=1, max=1_000_000,
                            update=_training_field_edited,
                            description="Gaussian-splat optimisation steps in all (the engine's default and the "
                                        "balanced preset: 1000; the paper uses 10,000, hours on a CPU)")
    rounds: IntProperty(name="Rounds", default=_DEFAULTS["rounds"], min=0, max=20, update=_training_field_edited,
                        description="Hallucination rounds: regenerate pseudo views this many times")
    resolution_scale: FloatProperty(name="Resolution", default=_DEFAULTS["resolution_scale"], min=0.05, max=1.0,
                                    subtype="FACTOR",
                                    update=_training_field_edited,
                                    description="Train on images downscaled by this factor")
    max_side: IntProperty(name="Max Size", default=_DEFAULTS["max_side"], min=0, max=16384, subtype="PIXEL",
                          update=_training_field_edited,
                          description="Train on views at most this many pixels on their longer side, after "
                                      "Resolution (0: no cap). The preset's cap keeps large photos to minutes "
                                      "on a CPU; the splats render at any size")
    generator: EnumProperty(name="Generator", items=GENERATORS, default=_DEFAULTS["prior"],
                            update=_training_field_edited)
    train_job: StringProperty(name="Train Job", subtype="DIR_PATH", options={"PATH_SUPPORTS_BLEND_RELATIVE"},
                              description="Job folder of the training run")
    result_object: PointerProperty(name="Result", type=bpy.types.Object, description="Imported splat object")
    max_display: IntProperty(name="Viewport Splats", default=200_000, min=0, update=_update_display,
                             description="At most this many splats drawn in the viewport, the most visible "
                                         "(opacity x size) first (0: all); renders use all")
    splat_size: FloatProperty(name="Splat Size", default=DEFAULT_SPLAT_SIZE, min=0.5, max=10.0,
                              update=_update_display,
                              description="Viewport proxy half-size in standard deviations: each Gaussian is drawn "
                                          "out to this distance (3: the engine's radius; smaller is faster but cuts "
                                          "edges). Renders size each splat where its alpha reaches 1/255")
    setup_render_on_import: BoolProperty(
        name="Set Up Rendering", default=True,
        description="On import, set the scene's render settings so splats look like the engine's render "
                    "(transparent bounces, samples, view transform; each change reported in the Info editor)")
    colour_mode: EnumProperty(name="Colours", items=COLOUR_ITEMS, default=DEFAULT_COLOUR_MODE,
                              description="How splat colours meet Blender's colour management")
    validate_source: StringProperty(name="Dataset", subtype="DIR_PATH", options={"PATH_SUPPORTS_BLEND_RELATIVE"},
                                    description="A scene with held-out test views (e.g. NeRF-synthetic) to validate on")
    validate_views: IntProperty(name="Train Views", default=8, min=1, max=200,
                                description="Training views picked evenly from the dataset's train split")
    validate_job: StringProperty(name="Validate Job", subtype="DIR_PATH", options={"PATH_SUPPORTS_BLEND_RELATIVE"},
                                 description="Job folder of the validation run")


CLASSES = (GSGS_AddonPreferences, GSGS_OT_check_engine, GSGS_SceneSettings)


def register() -> None:
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Scene.gsgs = PointerProperty(type=GSGS_SceneSettings)


def unregister() -> None:
    del bpy.types.Scene.gsgs
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
