"""Install Engine, the add-on's half: where the engine goes, starting and watching the installer.

The work itself is engine_installer.py, a standard-library script run as a child process by the
Python the engine will use (Blender's own unless the artist names one); the add-on never imports
torch. Each install makes a new folder `<extension user folder>/engines/engine-<time>`; only a
finished one carries the INSTALLED marker, and only then does Engine Python point at it (then the
engines before it are deleted). A failure or a cancel deletes the new folder and leaves Engine
Python as it was. In the UI a bpy.app.timers callback polls the child (as job_runner does for
jobs); headless (the bpy module, `blender --background`) the operator waits for the end.

The preferences' install section lives here too (InstallPreferences, draw_preferences), so that
preferences.py only mixes it in.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import bpy
from bpy.props import EnumProperty, StringProperty

from gsgs_engine import GsgsError, __version__ as ADDON_VERSION

from . import engine_installer, job_runner

HERE = Path(__file__).resolve().parent
CHECKOUT = HERE.parent  # gsgs_blender/ next to pyproject.toml in a source checkout
ENGINES = "engines"
TIMER_INTERVAL_S = 0.5
KILL_GRACE_S = 15.0  # after a cancel's SIGTERM the installer removes its folder; then kill()

TORCH_BUILDS = [
    ("auto", "Auto", "The CUDA build when an NVIDIA GPU is present (nvidia-smi lists one), else the CPU build"),
    ("cpu", "CPU", f"The CPU build, from Torch Index or PyTorch's CPU index ({engine_installer.TORCH_CPU_INDEX}): "
                   "a 0.19 GB download on Linux, against about 2.9 GB for the CUDA build"),
    ("cuda", "CUDA", "The CUDA build (NVIDIA GPUs): Linux from the package index, Windows from PyTorch's CUDA "
                     "index; several GB"),
    ("index", "Package Index", "Whatever torch the package index serves (PyPI on Linux: the CUDA build); use "
                               "it where PyTorch's own index cannot be reached but a mirror or a local wheel "
                               "folder (pip's find-links) has torch"),
]


class InstallPreferences:
    """The Install Engine settings, mixed into the add-on preferences."""

    install_python: StringProperty(
        name="Engine Base Python", subtype="FILE_PATH", default="",
        description="The Python (3.11 to 3.13) Install Engine builds the engine's environment from; empty: "
                    "Blender's own Python")
    install_index_url: StringProperty(
        name="Package Index", default="",
        description="Package index URL for every pip step of Install Engine (a mirror, a local index); "
                    "empty: pip's own configuration (PyPI unless pip.conf or PIP_INDEX_URL says otherwise). "
                    "Extra indexes and find-links from pip's configuration still apply")
    torch_build: EnumProperty(name="Torch Build", items=TORCH_BUILDS, default="auto",
                              description="Which torch Install Engine installs")
    torch_index_url: StringProperty(
        name="Torch Index", default="",
        description="Package index URL for the torch step; empty: PyTorch's index for the chosen build "
                    "(the package index for Package Index, and for CUDA on Linux)")


def engines_dir(folder: str = "") -> Path:
    """Where installed engines live: `folder`, else the extension's user folder (engines/)."""
    if folder:
        return Path(folder)
    try:
        base = Path(bpy.utils.extension_path_user(__package__, path="", create=True))
    except (ValueError, TypeError):  # registered from a checkout, not as an extension
        base = Path(bpy.utils.user_resource("DATAFILES", path="gsgs", create=True))
    return base / ENGINES


def engine_source() -> Path:
    """The engine wheel the extension zip carries (engine/), else this checkout (pip builds it)."""
    wheels = sorted((HERE / "engine").glob(f"gsgs-{ADDON_VERSION}-*.whl"))
    if wheels:
        return wheels[-1]
    if (CHECKOUT / "pyproject.toml").is_file() and (CHECKOUT / "gsgs_engine").is_dir():
        return CHECKOUT
    raise GsgsError(f"no engine wheel in {HERE / 'engine'}: this add-on was not built by `make extension`; "
                    "rebuild and install the zip, or point Engine Python at an environment with the engine")


def base_python(prefs) -> str:
    return bpy.path.abspath(prefs.install_python) if prefs.install_python else sys.executable


def installed_engines(folder: str = "") -> list[Path]:
    root = engines_dir(folder)
    return sorted(p for p in root.glob("engine-*") if (p / engine_installer.MARKER).is_file()) if root.is_dir() else []


def is_ours(python: str, folder: str = "") -> bool:
    """True when `python` is the interpreter of an environment Install Engine made."""
    try:  # the folder, not the file: a venv's bin/python is a link to its base Python
        return Path(python).parent.resolve().is_relative_to(engines_dir(folder).resolve())
    except (OSError, ValueError):
        return False


def remove_engines(folder: str = "", keep: Path | None = None) -> list[Path]:
    """Delete the engines in `folder` (all but `keep`), leftovers of interrupted installs and the
    progress files and logs of earlier installs; the environments deleted."""
    root = engines_dir(folder)
    gone = []
    for path in sorted(root.glob("engine-*")) if root.is_dir() else []:
        if keep is not None and (path.name == keep.name or path.name.startswith(keep.name + ".install.")):
            continue
        if path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
            gone.append(path)
        else:
            path.unlink(missing_ok=True)
    return gone


@dataclass
class InstallRun:
    """One installer child: its folder, progress file and process."""

    env: Path
    progress_file: Path
    process: subprocess.Popen
    state: str = "running"  # running | ok | error | cancelled
    message: str = ""
    last_event: dict = field(default_factory=dict)
    final: dict = field(default_factory=dict)
    cancel_at: float | None = None
    started: float = field(default_factory=time.monotonic)
    on_finish: list[Callable[["InstallRun"], None]] = field(default_factory=list)
    finished_handled: bool = False
    _offset: int = 0

    @property
    def finished(self) -> bool:
        return self.state != "running"

    @property
    def log_path(self) -> Path:
        return self.progress_file.with_suffix(".log")

    def status_line(self) -> str:
        ev = self.last_event
        if not ev:
            return "starting the installer"
        text = f"step {ev.get('n', 0)}/{ev.get('of', 0)}: {ev.get('label', '')}"
        return text + (f"  ({ev['mb']:.0f} MB downloaded)" if ev.get("mb") else "")

    def _read(self) -> None:
        try:
            with open(self.progress_file, "rb") as fh:
                fh.seek(self._offset)
                data = fh.read()
        except FileNotFoundError:
            return
        end = data.rfind(b"\n") + 1  # only whole lines
        self._offset += end
        for line in data[:end].decode("utf-8", errors="replace").splitlines():
            try:
                event = json.loads(line)
            except json.JSONDecodeError:
                continue
            if "state" in event:
                self.final = event
            self.last_event = event

    def poll(self) -> None:
        self._read()
        if self.finished:
            return
        rc = self.process.poll()
        if rc is None:
            if self.cancel_at is not None and time.monotonic() - self.cancel_at > KILL_GRACE_S:
                self._signal(signal.SIGKILL if os.name != "nt" else None)
            return
        self._read()
        state = self.final.get("state")
        if state in ("ok", "error", "cancelled"):
            message = self.final.get("message", "")
        elif self.cancel_at is not None:
            state, message = "cancelled", "Install Engine cancelled; nothing was changed"
        else:
            state, message = "error", (f"Install Engine failed: the installer exited with code {rc} "
                                       f"without finishing (log: {self.log_path})")
        if state != "ok" and self.env.exists():  # the installer cleans up; a killed one cannot
            shutil.rmtree(self.env, ignore_errors=True)
        self.state, self.message = state, message

    def cancel(self) -> None:
        """Stop the installer and its pip: SIGTERM to its process group (it deletes its folder), kill later."""
        if self.finished or self.cancel_at is not None:
            return
        self.cancel_at = time.monotonic()
        self._signal(signal.SIGTERM if os.name != "nt" else None)

    def _signal(self, sig) -> None:
        """`sig` to the installer's whole process group (its pip too); Windows: terminate the installer."""
        try:
            if sig is None:
                self.process.terminate()
            else:
                os.killpg(self.process.pid, sig)
        except (ProcessLookupError, PermissionError):
            pass

    def wait(self, timeout: float | None = None, echo: bool = True) -> str:
        """Headless: poll until the end, a progress line whenever the step changes."""
        shown = None
        while not self.finished:
            self.poll()
            line = self.status_line()
            if echo and line.split("  (")[0] != shown:
                shown = line.split("  (")[0]
                print(f"gsgs install: {line}", flush=True)
            if timeout is not None and time.monotonic() - self.started > timeout and self.cancel_at is None:
                self.cancel()
            time.sleep(0.2)
        return self.state


CURRENT: dict[str, InstallRun] = {}  # "run": the live or last install of this session


def current() -> InstallRun | None:
    return CURRENT.get("run")


def start(prefs, folder: str = "", on_finish: Callable[[InstallRun], None] | None = None,
          use_timer: bool | None = None) -> InstallRun:
    """Start the installer child for a new engine folder; returns at once."""
    run = current()
    if run is not None and not run.finished:
        raise GsgsError("Install Engine is already running; wait for it or cancel it")
    source = engine_source()
    python = base_python(prefs)
    root = engines_dir(folder)
    root.mkdir(parents=True, exist_ok=True)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    env, k = root / f"engine-{stamp}", 1
    while env.exists():
        k += 1
        env = root / f"engine-{stamp}-{k}"
    progress = root / f"{env.name}.install.jsonl"
    argv = [python, str(HERE / "engine_installer.py"), "--env", str(env), "--source", str(source),
            "--progress", str(progress), "--torch", prefs.torch_build]
    if prefs.install_index_url:
        argv += ["--index-url", prefs.install_index_url]
    if prefs.torch_index_url:
        argv += ["--torch-index-url", prefs.torch_index_url]
    try:
        process = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                   stdin=subprocess.DEVNULL, env=job_runner.engine_env(None),
                                   start_new_session=os.name != "nt")
    except OSError as exc:
        raise GsgsError(f"Install Engine cannot start {python!r} ({exc}); set Engine Base Python to a "
                        "Python 3.11 to 3.13") from exc
    run = InstallRun(env=env, progress_file=progress, process=process)
    if on_finish is not None:
        run.on_finish.append(on_finish)
    CURRENT["run"] = run
    if use_timer is None:
        use_timer = job_runner.ui_available()
    if use_timer and not bpy.app.timers.is_registered(_timer):
        bpy.app.timers.register(_timer, first_interval=TIMER_INTERVAL_S, persistent=True)
    return run


def finish(run: InstallRun) -> None:
    """Fire the on_finish callbacks once (from the timer or after a headless wait)."""
    if run.finished_handled:
        return
    run.finished_handled = True
    for callback in run.on_finish:
        try:
            callback(run)
        except Exception as exc:  # noqa: BLE001 (the timer must survive; the message says what failed)
            run.state, run.message = "error", f"{type(exc).__name__} after Install Engine: {exc}"
            print(f"gsgs: {run.message}", file=sys.stderr)


def _timer() -> float | None:
    run = current()
    if run is None:
        return None
    run.poll()
    for window in getattr(bpy.context.window_manager, "windows", []):
        for area in window.screen.areas:
            if area.type == "PREFERENCES":
                area.tag_redraw()
    if run.finished:
        finish(run)
        return None
    return TIMER_INTERVAL_S


def stop_timer() -> None:
    if bpy.app.timers.is_registered(_timer):
        bpy.app.timers.unregister(_timer)


def draw_preferences(prefs, layout) -> None:
    """The preferences' Install Engine section: settings, buttons, progress and the last result."""
    box = layout.box()
    box.label(text="Engine install (a Python environment with torch, pycolmap, OpenCV and the engine)")
    col = box.column()
    col.prop(prefs, "install_python")
    col.prop(prefs, "torch_build")
    col.prop(prefs, "install_index_url")
    col.prop(prefs, "torch_index_url")
    run = current()
    if run is not None and not run.finished:
        ev = run.last_event
        factor = (ev.get("n", 1) - 1) / max(1, ev.get("of", 1)) if ev else 0.0
        box.progress(factor=factor, type="BAR", text=run.status_line())
        if ev.get("torch"):
            box.label(text=ev["torch"][:120])
        box.operator("gsgs.cancel_engine_install", icon="CANCEL")
        return
    row = box.row()
    engines = installed_engines()
    row.operator("gsgs.install_engine", text="Reinstall Engine" if engines else "Install Engine", icon="IMPORT")
    if engines:
        row.operator("gsgs.uninstall_engine", icon="TRASH")
    if run is not None and run.message:
        box.label(text=run.message[:200], icon="CHECKMARK" if run.state == "ok" else "ERROR")
        for line in run.final.get("warnings", []):
            box.label(text=line[:200], icon="INFO")


def shutdown() -> None:
    """Add-on disabled: stop the timer and a live install (it deletes its half-made folder)."""
    stop_timer()
    run = current()
    if run is not None and not run.finished:
        run.cancel()
        deadline = time.monotonic() + KILL_GRACE_S + 5.0
        while not run.finished and time.monotonic() < deadline:
            run.poll()
            time.sleep(0.2)
    CURRENT.clear()
