"""Helpers every operator module shares: new job folders, launching jobs, reporting errors.

Operators live in ops_photos (photos -> cameras), ops_paths (pseudo paths), ops_train
(train / cancel / resume / validate) and ops_result (import splats); operators.py only
collects them for registration, so none of them imports it. A job is started the
same way everywhere: write the folder, start the engine child, and either poll it from a
timer (interactive Blender) or wait for it (the bpy module and --background).
"""

from __future__ import annotations

import functools
import os
import time
from pathlib import Path
from typing import Callable

import bpy

from gsgs_engine import GsgsError
from gsgs_engine.job import Job

from . import job_runner
from .preferences import get_prefs, jobs_root


def new_job_dir(context, task: str) -> Path:
    """A fresh, uniquely named job folder under the jobs root."""
    root = jobs_root(context)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    path = root / f"{task}-{stamp}"
    k = 1
    while path.exists():
        k += 1
        path = root / f"{task}-{stamp}-{k}"
    return path


def stored_path(path: Path) -> str:
    """A job folder as the .blend keeps it: relative (//...) when the file is saved, so a project
    folder moved to another machine still finds its jobs."""
    if bpy.data.filepath:
        try:
            return bpy.path.relpath(str(path))
        except ValueError:  # another drive (Windows)
            pass
    return str(path)


def launch(context, job: Job, on_finish: Callable[[job_runner.JobRun], None] | None = None,
           timeout: float | None = None) -> job_runner.JobRun:
    """Start the engine on `job`. Interactive: returns at once, a timer polls. Headless: waits, at most
    `timeout` seconds (None or 0: no limit); past it the job is cancelled and a GsgsError says so."""
    prefs = get_prefs(context)
    python = bpy.path.abspath(prefs.python_path)
    engine_root = bpy.path.abspath(prefs.engine_root) if prefs.engine_root else None
    interactive = job_runner.ui_available()
    args, env, grace = cluster_launch(prefs)
    run = job_runner.start(job.root, python, engine_root=engine_root, on_finish=on_finish, use_timer=interactive,
                           extra_args=args, extra_env=env, cancel_grace_s=grace)
    if not interactive:
        job_runner.wait_for(run, timeout=timeout or None)
    return run


CLUSTER_CANCEL_GRACE_S = 90.0  # a cancelled cluster run finishes its step and sends its checkpoint back first


def cluster_launch(prefs) -> tuple[list[str], dict, float | None]:
    """(run-job arguments, environment, cancel grace) of the "Run jobs on" preference. For a Ray cluster the
    child process is the driver: it sends the job and mirrors it back into the job folder, so progress,
    Cancel, Resume and import work as for a local job. The address rule is checked before anything starts."""
    if getattr(prefs, "run_on", "local") != "ray":
        return [], {}, None
    from gsgs_engine.cluster.address import check_address

    env = {}
    if prefs.ray_token:
        env = {"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": prefs.ray_token}
    address = check_address(prefs.ray_address, {**os.environ, **env})
    return ["--ray", address, "--ray-cpus", str(int(prefs.ray_cpus)), "--ray-gpus",
            "1" if prefs.device == "cuda" else "0"], env, CLUSTER_CANCEL_GRACE_S


def scene_callback(scene_name: str, fn: Callable) -> Callable[[job_runner.JobRun], None]:
    """An on_finish callback that finds its scene by name (objects may have been replaced since)."""
    @functools.wraps(fn)
    def callback(run: job_runner.JobRun) -> None:
        scene = bpy.data.scenes.get(scene_name)
        if scene is not None:
            fn(scene, run)
    return callback


def timeout_property():
    """The `timeout` operator property of every job-starting operator (headless scripts)."""
    return bpy.props.FloatProperty(
        name="Timeout", default=0.0, min=0.0, subtype="TIME_ABSOLUTE", unit="TIME_ABSOLUTE",
        options={"SKIP_SAVE"},
        description="Headless scripts (no UI): give up after this many seconds, cancelling the job "
                    "(0: wait until it ends). Interactive Blender never waits: the job runs in the background")


def report_error(op, exc: Exception) -> set:
    message = str(exc) if isinstance(exc, GsgsError) else f"{type(exc).__name__}: {exc}"
    op.report({"ERROR"}, message)
    return {"CANCELLED"}


def job_run(path: str) -> job_runner.JobRun | None:
    """The live or recorded run of a job folder path stored on the scene ('' -> None)."""
    if not path:
        return None
    folder = Path(bpy.path.abspath(path))
    if not (folder / "job.json").is_file():
        return None
    return job_runner.attach(folder)
