"""A training time estimate the Train panel states before a job starts.

Scaled from `gsgs bench sparse` protocol cells run on the project's 2-core CPU machine (seed 0, 1000 steps, two
threads, one after another with nothing else running, 2026-11-29 17:42-17:57, session 30's build; the script is
docs/runs/speed/s30/references.sh), one reference per recipe the engine can run, because they differ more than any
single factor allows:
  - plain 3DGS: LLFF flower, 3 views at 504x378, 130.0 s (150,675 Gaussians: without the count control real
    photos grow them unchecked);
  - `--prior auto` where the cameras look at a common point (an object orbit: MVS init, count control,
    dropout, the binocular shift every second step, no pseudo views, SH degree 2 from 8 views): NeRF-synthetic
    lego, 8 views at 400x400, 97.7 s;
  - `--prior auto` on a forward-facing rig (densified by absolute gradients, density-guided dropout, the binocular
    shift every step at half size, warp-inpaint pseudo views at half size): LLFF flower at 504x378, 197.9 s.
  - an inward shell (cameras on the walls of a room or dome looking in; `--prior auto` with the background sphere and
    the binocular shift every step): Panoptic frame 0, 9 cameras at 640x360, and the 4D recipe of a multi-view video:
    the same 9 cameras, frames 0-9 at 320x180 (session 37: each timed right after the lego cell and scaled by
    its seconds over that cell's, so they sit on the same day as the references above).
  The machine's day moves such figures by tens of percent (the same f6f2ab9 flower cell took 382 s one morning and
  531 s that afternoon, and 319 s the day after): the machine probe below scales them. The references before
  (session 12's build, 88.1 / 63.5 / 142.3 s at a probe of 17.9 ms) no longer matched this build: on a fresh
  timings log the Santorini workflow below was stated 96 s and trained in 132 s (27 % short; session 30). Which of
  the changes since (and how much of the VM's day) account for it was not measured.
Which recipe auto runs is read from the training cameras as the engine's effect plan reads it: the
optical axes meet at a point (gsgs_engine.cameras.focus_point) -> the orbit recipe, or the inward shell's where the
scene's sparse points lie out at the cameras' shell (gsgs_engine.effect_plan.rig_layout), else forward-facing; an
imported multi-view video -> the 4D recipe.
Per step the time grows less than linearly with a view's pixels: seconds per step ~ pixels^0.71 (measured
between 200x200 and 1600x871 px runs of an earlier kernel, issue 15's photo job).
Checked (not fitted) on the default headless workflow, scripts/reconstruct.py on photos_santorini (3 photos,
balanced preset: 1000 steps of auto at 640x340, an orbit by the cameras), right after the reference cells with a
fresh timings log: see docs/speed.md, "Session 30" (session 12 with its references: stated ~82 s, trained 88.8 s).
It is a rough figure (scene content and Gaussian counts move it too) and the panel says so.

This machine's own jobs correct it: a training job started from the add-on keeps the uncorrected estimate in its
folder (estimate.json); when it finishes, its measured training seconds are added to a small log beside the
installed engines (train_timings.jsonl; GSGS_TIMINGS names another file), and later estimates are scaled by the
median of measured / estimated over the last few jobs of the same recipe (of any recipe while none of it has run).
Jobs too short to say anything (under MIN_LEARN_ITERS steps or MIN_LEARN_SECONDS) are not learned from.
Measured (session 9, the Santorini workflow twice on a fresh log, a faster day than the references of then): the
first run stated 200 s and trained 123 s; the second, corrected by the first, stated 123 s and trained 130 s.

Before this machine has finished a job the references alone can be tens of percent off (the first run above),
because a shared virtual machine's speed moves from day to day and a user's machine is not the reference one. So the
Train operator first probes the machine (`python -m gsgs_engine bench machine`: one fixed render with backward on the
compiled kernel, about 2 s with the interpreter's start; gsgs_engine/bench/machine_speed.py) and scales the
references by its time over PROBE_REFERENCE_MS, the same probe on the reference cells' machine and day. The probe is
kept beside the timings log (machine_probe.json) and re-run when older than PROBE_MAX_AGE_S; the panel shows the
last one. The learned factor then corrects what the probe leaves (the recipe's content, the Gaussian count).
Measured (session 10, with that build's probe of 22.5 ms): the probe read 22-23 ms on an idle machine and 44 ms beside
a two-thread training. The
Santorini workflow on a fresh log with a two-thread training beside it stated 169 s (the probe's factor 1.75) and
trained in 200.9 s: 16 % short, where the references alone (96.7 s) would have been 52 % short. The probe renders SH
degree 3, whose projection session 11 made about twice as fast: its reference was measured again with the cells.

On a GPU (the job trains with gsplat: Device "cuda", or "auto" where the last machine probe found a CUDA device that
gsplat can use) the estimate starts from the same protocol cells trained on CUDA instead (REFERENCES_CUDA: one NVIDIA
H200, seed 0, 1000 steps, one cell at a time, 2026-12-04, docs/speed.md "Session 33"): the orbit recipe on lego 12.2
s, the forward-facing recipe on flower 24.6 s. Plain 3DGS was not timed there, so a plain job on a GPU gets no
figure (the panel says so, beside the CPU's) and teaches nothing. The CPU probe does not apply to a GPU; the
view-size scaling and the long-schedule factors are the CPU's (not measured on a GPU), and the user's GPU is not that
H200: GPU jobs teach their own correction (recipe keys "orbit@cuda" and so on), separate from the CPU's, from the first finished one.
gsplat's one-time kernel build on a new machine (86 s on the H200) is not in the figure; the text says so.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import time
from pathlib import Path

from gsgs_engine import GsgsError

REFERENCE_ITERS = 1000
# recipe -> (seconds for REFERENCE_ITERS steps, pixels of a training view) measured as above
REFERENCES = {
    "plain": (130.0, 504 * 378),
    "orbit": (97.7, 400 * 400),
    "forward": (197.9, 504 * 378),  # the 1000-step recipe, which densifies by absolute gradients
    # Session 37 (docs/runs/speed/s37/estimate_runs.sh references, run twice): each run right after the lego orbit
    # cell on a quiet machine (probe 14-19 ms), taken as 97.7 s x the mean over the two rounds of its seconds over that
    # cell's: an inward shell (Panoptic frame 0, 9 cameras at 640x360, auto: the binocular view every step and the
    # background sphere) 100.2 / 56.5 and 106.8 / 54.8 s, and the 4D recipe (the same cameras, frames 0-9 at 320x180,
    # auto) 51.3 / 56.5 and 46.5 / 54.8 s
    "inward": (97.7 * (100.2 / 56.5 + 106.8 / 54.8) / 2, 640 * 360),
    "video": (97.7 * (51.3 / 56.5 + 46.5 / 54.8) / 2, 320 * 180),
}
RECIPE_NAMES = {"plain": "plain 3DGS", "orbit": "the orbit recipe", "inward": "the inward-shell recipe",
                "forward": "the forward-facing recipe", "video": "the 4D recipe"}
# recipe -> seconds for REFERENCE_ITERS steps on CUDA, the same cells as REFERENCES (pixels as there), trained with
# `"backend": "cuda"` on one NVIDIA H200 (2026-12-04, docs/speed.md "Session 33"); plain 3DGS not measured there
REFERENCES_CUDA = {"orbit": 12.2, "forward": 24.6}
GPU_REFERENCE_DEVICE = "NVIDIA H200"
DEVICES = ("cpu", "cuda")
# The orbit recipe of long schedules renders the binocular view at every step, not every second one: lego auto at
# 1000 steps took 201 s that way against 157 s, back to back on a quiet machine (2026-11-26, docs/speed.md).
ORBIT_EVERY_STEP_FACTOR = 201.0 / 157.0
# ... and the forward-facing recipe of long schedules renders the binocular view at full size, not half: flower auto
# at 1000 steps trained in 160.1 s that way against 137.8 s (means of seeds 0-2 of the 3-seed grid, 2026-11-27, one
# cell at a time with kernel builds beside some cells: not a quiet pair; docs/speed.md).
FORWARD_FULL_VIEW_FACTOR = 160.1 / 137.8
# ... and the forward-facing recipe (the reference; the long one too since session 42) densifies by absolute
# gradients since session 29 (AbsGS; the compiled backward computes the statistic), which the other generators do
# not: flower auto steps 1-1000 172.9 / 175.9 s without, 184.0 / 186.3 s with it (two pairs alternating on a quiet
# machine, 2026-11-29; docs/speed.md, "Session 29"). At 3000 steps LLFF cells with it trained ~1.14x as long as
# without (cells of two days, not a quiet pair; docs/sparse_techniques.md "Session 42"), so a long forward run may
# take ~7 % more than stated until the machine's correction (timings log) learns it.
FORWARD_ABSGRAD_FACTOR = (184.0 + 186.3) / (172.9 + 175.9)
# ... and the orbit recipe below 3000 steps learns colour, scales and rotations at 3x 3DGS's rates since session 45
# (effect_plan.ATTRIBUTE_LR_SCALE): larger footprints sooner, more Gaussians. Lego auto at 1000 steps, the build before
# and after alternating twice on a quiet machine (2026-12-06, docs/sparse_techniques.md "Session 45"): 84.2 / 79.1 s
# before, 90.3 / 116.5 s after (the VM's noise: the pairs' ratios are 1.07 and 1.47), so the sum's ratio.
ORBIT_ATTRIBUTE_LR_FACTOR = (90.3 + 116.5) / (84.2 + 79.1)
# ... and adds the depth distortion's half-size composite every 8th step (session 47; effect_plan.AUTO_ORBIT_TECHNIQUES):
# lego auto at 1000 steps, the recipe without and with it alternating twice on a quiet machine (2026-12-06,
# docs/sparse_techniques.md "Session 47"): 90.8 / 94.8 s without, 95.6 / 101.4 s with it.
ORBIT_DISTORTION_FACTOR = (95.6 + 101.4) / (90.8 + 94.8)
# ... and so does the forward-facing recipe below 3000 steps: LLFF cells of session 45 with them against session 44's
# without, the same VM, one cell at a time (flower seeds 1-2, horns seeds 0-2; not a quiet pair: some of session 44's
# cells ran beside other work, so the factor is if anything low): 1116.9 s against 826.7 s of training.
FORWARD_ATTRIBUTE_LR_FACTOR = 1116.9 / 826.7
MIN_PIXEL_FACTOR = 0.05  # below ~100x100 px per-step overheads dominate
PIXEL_EXPONENT = 0.71
TIMINGS_FILE = "train_timings.jsonl"
ESTIMATE_FILE = "estimate.json"  # in a job folder: what was estimated when it started
KEEP_TIMINGS = 50  # lines the log keeps
USE_LAST = 5  # jobs a correction is the median of
MIN_LEARN_ITERS = 100
MIN_LEARN_SECONDS = 10.0
FACTOR_RANGE = (0.2, 5.0)  # a correction outside this says more about a broken log than about the machine
PROBE_FILE = "machine_probe.json"  # beside the timings log: the machine's last speed probe
PROBE_REFERENCE_MS = 25.1  # `gsgs bench machine` around the reference cells (2 threads): median of 6, 23.4-31.1
PROBE_MAX_AGE_S = 900.0  # the Train operator probes again after this
PROBE_TIMEOUT_S = 60.0


def train_size(width: int, height: int, resolution_scale: float, max_side: int = 0) -> tuple[int, int]:
    """The size views of width x height train at: scaled by resolution_scale, then the longer side capped
    at max_side (0: no cap), as gsgs_engine.io.loader.load_scene does."""
    scale = resolution_scale
    longest = max(width, height) * scale
    if max_side and longest > max_side:
        scale *= max_side / longest
    return round(width * scale), round(height * scale)


def recipe(generator: str, cameras=None, points=None, video: bool = False) -> str:
    """Which measured recipe a run will be: "plain", "orbit", "inward", "forward" or "video" (see REFERENCES).

    A multi-view video trains the 4D model ("video", whatever the generator: its weights-free recipe renders no
    extra views). The generative priors (warp, diffusion) always render pseudo views; auto does where the cameras
    do not look at a common point, as the effect plan decides (cameras: gsgs_engine Camera objects). Where they do,
    the plan's rig reading (gsgs_engine.effect_plan.rig_layout) on the scene's sparse `points` (N x 3, the same
    world as the cameras) tells an inward shell (the background sphere, the binocular view at every step) from an
    object orbit; without enough points the engine triangulates its own, which the add-on cannot see beforehand, so
    the figure is the orbit's."""
    if video:
        return "video"
    if generator in ("none", "depth"):
        return "plain"
    if generator != "auto":
        return "forward"
    if cameras is not None and len(cameras) >= 2:
        from gsgs_engine.effect_plan import rig_layout

        layout = rig_layout(cameras, points)
        if layout["rig"] == "object orbit" or (layout["rig"] == "inward shell" and layout.get("unmeasured")):
            return "orbit"
        if layout["rig"] == "inward shell":
            return "inward"
    return "forward"


def job_device(device_setting: str, path: Path | None = None) -> str:
    """"cuda" when a job with the add-on's Device setting trains on a GPU as far as the add-on can tell ("cuda", or
    "auto" where the last machine probe found a CUDA device gsplat can use), else "cpu"."""
    if device_setting == "cuda":
        return "cuda"
    if device_setting == "auto":
        try:
            raw = json.loads((probe_path() if path is None else path).read_text())
            if isinstance(raw, dict) and raw.get("cuda"):
                return "cuda"
        except (OSError, ValueError, GsgsError):
            pass
    return "cpu"


def device_of(prefs) -> str:
    """job_device for the add-on's preferences: a job run elsewhere (a Ray cluster) keeps the CPU figure, as before."""
    if getattr(prefs, "run_on", "local") != "local":
        return "cpu"
    return job_device(getattr(prefs, "device", "auto"))


def timing_key(kind: str, device: str = "cpu") -> str:
    """The timings log's recipe key: "orbit" on the CPU, "orbit@cuda" on a GPU."""
    if device not in DEVICES:
        raise GsgsError(f"unknown training device {device!r}; choose one of {', '.join(DEVICES)}")
    return kind if device == "cpu" else f"{kind}@{device}"


def estimate_seconds(iterations: int, width: int, height: int, resolution_scale: float, generator: str,
                     max_side: int = 0, cameras=None, device: str = "cpu", points=None,
                     video: bool = False) -> float | None:
    """Rough seconds of a training run of `iterations` steps on views of width x height, from the reference
    runs alone (`machine_factor` corrects it for this machine); on device "cuda" from the GPU references, None where
    the recipe has none there."""
    from gsgs_engine.effect_plan import AUTO_LONG_STEPS

    kind = recipe(generator, cameras, points, video)
    seconds, ref_pixels = REFERENCES[kind]
    timing_key(kind, device)  # an unknown device stops here
    if device != "cpu":
        if kind not in REFERENCES_CUDA:
            return None
        seconds = REFERENCES_CUDA[kind]
    if kind == "orbit" and iterations >= AUTO_LONG_STEPS:  # the shifted view at every step (effect_plan)
        seconds *= ORBIT_EVERY_STEP_FACTOR
    elif kind == "orbit":  # ... and below it the raised colour, scale and rotation rates and the depth distortion
        seconds *= ORBIT_ATTRIBUTE_LR_FACTOR * ORBIT_DISTORTION_FACTOR
    if kind == "forward" and generator != "auto":  # no absolute gradients
        seconds /= FORWARD_ABSGRAD_FACTOR
    if kind == "forward" and generator == "auto" and iterations >= AUTO_LONG_STEPS:  # ... the view at full size
        seconds *= FORWARD_FULL_VIEW_FACTOR
    elif kind == "forward" and generator == "auto":  # ... and below it the raised colour, scale and rotation rates
        seconds *= FORWARD_ATTRIBUTE_LR_FACTOR
    w, h = train_size(width, height, resolution_scale, max_side)
    pixels = max(1.0, w * h)
    per_step = seconds / REFERENCE_ITERS * max(pixels / ref_pixels, MIN_PIXEL_FACTOR) ** PIXEL_EXPONENT
    return iterations * per_step


def timings_path() -> Path:
    """The log of finished jobs' estimated and measured seconds: GSGS_TIMINGS, else beside the installed engines."""
    if os.environ.get("GSGS_TIMINGS"):
        return Path(os.environ["GSGS_TIMINGS"])
    from .engine_install import engines_dir

    return engines_dir().parent / TIMINGS_FILE


def read_timings(path: Path | None = None) -> list[dict]:
    """The log's records, oldest first; lines that do not parse are skipped (a log is never a reason to fail)."""
    path = timings_path() if path is None else path
    try:
        lines = path.read_text().splitlines()
    except OSError:
        return []
    records = []
    for line in lines:
        try:
            rec = json.loads(line)
            kind, _, device = str(rec.get("recipe")).partition("@")
            if (float(rec["estimated_s"]) > 0 and float(rec["train_s"]) > 0 and kind in REFERENCES
                    and (device or "cpu") in DEVICES):
                records.append(rec)
        except (ValueError, KeyError, TypeError):
            continue
    return records


def probe_path() -> Path:
    return timings_path().with_name(PROBE_FILE)


def read_probe(path: Path | None = None) -> dict | None:
    """The last probe ({"time", "probe_ms", "threads", ...}) or None; a damaged file counts as none."""
    try:
        probe = json.loads((probe_path() if path is None else path).read_text())
        return probe if float(probe["probe_ms"]) > 0 and float(probe["time"]) > 0 else None
    except (OSError, ValueError, KeyError, TypeError, GsgsError):
        return None


def refresh_probe(python: str, engine_root: str | None = None, max_age_s: float = PROBE_MAX_AGE_S,
                  path: Path | None = None, timeout: float = PROBE_TIMEOUT_S) -> dict | None:
    """Probe the machine with the engine's interpreter unless the last probe is younger than max_age_s; returns the
    probe in use (None when there is none: no interpreter, no built kernel, a timeout). Never raises."""
    from .job_runner import engine_env

    try:
        path = probe_path() if path is None else path
    except GsgsError:
        return None
    last = read_probe(path)
    if last is not None and 0 <= time.time() - float(last["time"]) < max_age_s:
        return last
    if not python:
        return last
    try:
        done = subprocess.run([python, "-m", "gsgs_engine", "bench", "machine"], env=engine_env(engine_root),
                              capture_output=True, text=True, timeout=timeout)
        lines = [line for line in done.stdout.splitlines() if line.startswith("{")]
        result = json.loads(lines[-1]) if lines else {}
    except (OSError, ValueError, subprocess.SubprocessError):
        return last
    if not (isinstance(result.get("probe_ms"), (int, float)) and result["probe_ms"] > 0):
        if result.get("cuda") and last is None:  # no CPU kernel, but a GPU: keep that (job_device reads it)
            _write_probe(path, {"time": time.time(), "cuda": result["cuda"]})
        return last  # e.g. {"error": "the compiled CPU kernel is not built yet ...", "cuda": null}
    probe = {"time": time.time(), **result}
    _write_probe(path, probe)  # used for this estimate even where it cannot be kept
    return probe


def _write_probe(path: Path, probe: dict) -> None:
    """Replace the probe file with `probe` in one step; a folder that cannot be written is not an error."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(json.dumps(probe))
        os.replace(tmp, path)
    except OSError:
        pass


def probe_factor(path: Path | None = None) -> float:
    """The last probe's time over PROBE_REFERENCE_MS (clamped to FACTOR_RANGE); 1.0 without a probe."""
    probe = read_probe(path)
    if probe is None or not PROBE_REFERENCE_MS:
        return 1.0
    return min(max(float(probe["probe_ms"]) / PROBE_REFERENCE_MS, FACTOR_RANGE[0]), FACTOR_RANGE[1])


def machine_factor(kind: str, path: Path | None = None, device: str = "cpu") -> tuple[float, int]:
    """(measured / estimated, jobs it comes from) for recipe `kind` on this machine's `device`; (1.0, 0) before any
    job there. Before a job of the recipe, the device's other recipes speak for it (never the other device's)."""
    key = timing_key(kind, device)
    records = [r for r in read_timings(path) if ("@" in r["recipe"]) == (key != kind)]
    same = [r for r in records if r["recipe"] == key]
    use = (same or records)[-USE_LAST:]
    if not use:
        return 1.0, 0
    ratio = statistics.median(float(r["train_s"]) / float(r["estimated_s"]) for r in use)
    return min(max(ratio, FACTOR_RANGE[0]), FACTOR_RANGE[1]), len(use)


def write_job_estimate(job_dir, iterations: int, width: int, height: int, resolution_scale: float, generator: str,
                       max_side: int = 0, cameras=None, device: str = "cpu", points=None, video: bool = False) -> dict:
    """Keep the estimate of a job about to start in its folder (estimate.json): the references scaled by the last
    probe (on the CPU), before the learned correction, which it will then teach; returns it. A recipe without a
    reference on the device (plain 3DGS on a GPU) is kept with estimated_s None, and is not learned from."""
    reference_s = estimate_seconds(iterations, width, height, resolution_scale, generator, max_side, cameras, device,
                                   points, video)
    speed = probe_factor() if device == "cpu" else 1.0
    record = {"recipe": timing_key(recipe(generator, cameras, points, video), device), "device": device,
              "iterations": int(iterations), "size": list(train_size(width, height, resolution_scale, max_side)),
              "reference_s": reference_s, "probe_factor": speed,
              "estimated_s": None if reference_s is None else reference_s * speed}
    try:
        (Path(job_dir) / ESTIMATE_FILE).write_text(json.dumps(record))
    except OSError:  # the job runs all the same; it is only not learned from
        pass
    return record


def learn_from_job(job_dir, path: Path | None = None) -> str:
    """Add a finished job's estimated and measured training seconds to the log. Returns what it did, in words."""
    job_dir = Path(job_dir)
    try:
        estimate = json.loads((job_dir / ESTIMATE_FILE).read_text())
        metrics = json.loads((job_dir / "result" / "metrics.json").read_text())
    except (OSError, ValueError) as exc:
        return f"not learned from: {exc}"
    if estimate.get("estimated_s") is None:
        return f"not learned from: {estimate.get('recipe')} has no measured reference to correct"
    train_s, iters = metrics.get("train_seconds"), metrics.get("iterations")
    if not isinstance(train_s, (int, float)) or not isinstance(iters, int) or iters != estimate.get("iterations"):
        return "not learned from: the job's metrics do not match its estimate (resumed or changed?)"
    if iters < MIN_LEARN_ITERS or train_s < MIN_LEARN_SECONDS:
        return f"not learned from: {iters} steps in {train_s:.1f} s is too short to time this machine"
    backend = (metrics.get("plan") or {}).get("backend")  # the renderer the job used (gsgs_engine.reconstruct)
    ran_on = "cuda" if backend == "cuda" else "cpu" if backend in (None, "cpu", "cpu_legacy", "reference") else backend
    estimated_for = estimate.get("device", "cpu")
    if ran_on != estimated_for:
        return f"not learned from: trained on {backend}, the estimate is for the {estimated_for.upper()}"
    record = {"time": time.strftime("%Y-%m-%d %H:%M:%S"), "recipe": estimate["recipe"], "iterations": iters,
              "size": estimate.get("size"), "estimated_s": float(estimate["estimated_s"]), "train_s": float(train_s)}
    try:  # the log is a convenience: a folder that cannot be written never stops a result from being imported
        path = timings_path() if path is None else path
        lines = [json.dumps(r) for r in read_timings(path)][-(KEEP_TIMINGS - 1):] + [json.dumps(record)]
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text("\n".join(lines) + "\n")
        os.replace(tmp, path)
    except (OSError, GsgsError) as exc:
        return f"not learned from: the timings log cannot be written ({exc})"
    return f"learned: {record['recipe']} estimated {record['estimated_s']:.0f} s, took {train_s:.0f} s"


def format_duration(seconds: float) -> str:
    if seconds < 1:
        return "under 1 s"
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def estimate_text(scene, inputs: dict | None = None, device: str = "cpu") -> str:
    """'~N min on this machine ...' for the scene's training cameras and Train fields ('' without cameras);
    `inputs`: job_estimate_inputs(scene) when the caller has it already; `device`: job_device(the Device setting)."""
    inputs = job_estimate_inputs(scene) if inputs is None else inputs
    if inputs is None:
        return ""
    w, h = train_size(inputs["width"], inputs["height"], inputs["resolution_scale"], inputs["max_side"])
    kind = recipe(inputs["generator"], inputs["cameras"], inputs.get("points"), inputs.get("video", False))
    name = RECIPE_NAMES[kind]
    if device != "cpu":
        seconds = estimate_seconds(**inputs, device=device)
        if seconds is None:
            return (f"{name} on a GPU has no measured reference ({inputs['iterations']} steps on {w}x{h} px; far "
                    f"less than the ~{format_duration(estimate_seconds(**inputs))} a 2-core CPU takes)")
        factor, jobs = machine_factor(kind, device=device)
        where = (f"on this GPU, from {jobs} finished GPU job{'s' if jobs != 1 else ''}" if jobs else
                 f"on a GPU (measured on an {GPU_REFERENCE_DEVICE}; a first job on a new machine also builds "
                 "gsplat's kernels, about 1.5 min)")
        return f"~{format_duration(seconds * factor)} {where} ({inputs['iterations']} steps of {name} on {w}x{h} px)"
    seconds = estimate_seconds(**inputs)
    factor, jobs = machine_factor(kind)
    probed = read_probe() is not None and bool(PROBE_REFERENCE_MS)
    factor *= probe_factor()
    finished = f"{jobs} finished job{'s' if jobs != 1 else ''}"
    if probed:
        where = "on this machine (its speed probed" + (f", corrected by {finished})" if jobs else ")")
    else:
        where = f"on this machine, from {finished}" if jobs else "on a 2-core CPU"
    return (f"~{format_duration(seconds * factor)} {where} ({inputs['iterations']} steps of {name} on {w}x{h} px; "
            "a GPU is far faster)")


def job_estimate_inputs(scene) -> dict | None:
    """estimate_seconds' arguments for the scene's training cameras and Train fields (None without cameras)."""
    from . import camera_convert, pseudo_paths

    objs = pseudo_paths.training_camera_objects(scene)
    if not objs:
        return None
    sizes = [camera_convert.frame_of(o, scene)[:2] for o in objs]
    try:
        cameras = [camera_convert.camera_from_object(o, scene) for o in objs]
    except GsgsError:
        cameras = None
    s = scene.gsgs
    return {"iterations": s.iterations, "width": max(w for w, _ in sizes), "height": max(h for _, h in sizes),
            "resolution_scale": s.resolution_scale, "generator": s.generator, "max_side": s.max_side,
            "cameras": cameras, "points": pseudo_paths.sparse_points_world(s), "video": bool(s.video_source)}
