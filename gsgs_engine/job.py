"""The job folder: the contract between the add-on (or any script / scheduler) and the engine.

    job.json          schema version, task (sfm | train | validate), data, settings
    progress.jsonl    one JSON object a line: phase, step, total, losses, eta_s, message
    status.json       written last, atomically: ok | error | cancelled, with a message
    result/           point_cloud.ply, metrics.json, pseudo/round_k/*.png, renders,
                      background_sphere.png (a run with the background sphere: inward shells under auto)
    checkpoints/      enough to resume after a crash or a cancel
    log.txt

Standard library + numpy only: Blender's Python imports this module.
"""

from __future__ import annotations

import functools
import json
import math
import os
import socket
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gsgs_engine import GsgsError

SCHEMA_VERSION = 1
TASKS = ("sfm", "train", "validate")
STATES = ("running", "ok", "error", "cancelled")


def finite_json(obj: Any) -> Any:
    """`obj` with every NaN / Inf float replaced by None: JSON has no NaN, and a bare `NaN` token makes
    the file unreadable to strict parsers (browsers, jq, other languages)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_json(v) for v in obj]
    if hasattr(obj, "tolist") and not isinstance(obj, (str, bytes)):
        return finite_json(obj.tolist())
    return obj


def write_json_atomic(path: Path, data: Any) -> None:
    """Write JSON so a reader never sees a half-written file (temp file + rename); mode 0644 like every
    other output (mkstemp would leave 0600); NaN / Inf are written as null (finite_json)."""
    from gsgs_engine.write_errors import writing

    path = Path(path)
    with writing(path, path.name):
        _write_json_atomic(path, data)


def _write_json_atomic(path: Path, data: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as fh:
            json.dump(finite_json(data), fh, indent=2, sort_keys=False, default=_json_default, allow_nan=False)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, output_file_mode())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


@functools.lru_cache(maxsize=1)
def output_file_mode() -> int:
    """0644 less the process umask: the mode an ordinary open() gives, for files made with mkstemp (0600)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o644 & ~mask


def _json_default(obj: Any) -> Any:
    if hasattr(obj, "tolist"):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON-serialisable: {type(obj).__name__}")


@dataclass
class Job:
    """A job folder. `Job.create(...)` writes job.json; `Job.open(dir)` reads and validates it."""

    root: Path
    spec: dict = field(default_factory=dict)

    # -- paths ------------------------------------------------------------------------
    @property
    def spec_path(self) -> Path:
        return self.root / "job.json"

    @property
    def progress_path(self) -> Path:
        return self.root / "progress.jsonl"

    @property
    def status_path(self) -> Path:
        return self.root / "status.json"

    @property
    def result_dir(self) -> Path:
        return self.root / "result"

    @property
    def checkpoint_dir(self) -> Path:
        return self.root / "checkpoints"

    @property
    def log_path(self) -> Path:
        return self.root / "log.txt"

    @property
    def cancel_path(self) -> Path:
        """The add-on asks a running job to stop by creating this file (works on every OS)."""
        return self.root / "cancel.request"

    @property
    def task(self) -> str:
        return self.spec["task"]

    # -- creation / reading -----------------------------------------------------------
    @classmethod
    def create(cls, root: str | os.PathLike, task: str, data: dict | None = None,
               settings: dict | None = None, **extra: Any) -> "Job":
        if task not in TASKS:
            raise GsgsError(f"unknown job task {task!r}; expected one of {', '.join(TASKS)}")
        root = Path(root)
        root.mkdir(parents=True, exist_ok=True)
        spec = {"schema_version": SCHEMA_VERSION, "task": task, "data": data or {},
                "settings": settings or {}, "created": time.time(), **extra}
        write_json_atomic(root / "job.json", spec)
        return cls(root=root, spec=spec)

    @classmethod
    def open(cls, root: str | os.PathLike) -> "Job":
        root = Path(root)
        path = root / "job.json"
        if not path.is_file():
            raise GsgsError(f"{path}: no job.json here; create the job with the add-on or gsgs_engine.job.Job.create")
        try:
            spec = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise GsgsError(f"{path}: not valid JSON ({exc}); recreate the job") from exc
        version = spec.get("schema_version")
        if version != SCHEMA_VERSION:
            raise GsgsError(f"{path}: job schema version {version!r}, this engine reads {SCHEMA_VERSION}; "
                            "recreate the job with this version of the add-on")
        if spec.get("task") not in TASKS:
            raise GsgsError(f"{path}: task {spec.get('task')!r} is not one of {', '.join(TASKS)}")
        return cls(root=root, spec=spec)

    # -- progress and status -------------------------------------------------------------
    def emit(self, phase: str, step: int = 0, total: int = 0, losses: dict | None = None,
             eta_s: float | None = None, message: str = "", **extra: Any) -> dict:
        event = {"time": time.time(), "phase": phase, "step": int(step), "total": int(total),
                 "losses": losses or {}, "eta_s": eta_s, "message": message, **extra}
        self.root.mkdir(parents=True, exist_ok=True)
        with open(self.progress_path, "a") as fh:
            fh.write(json.dumps(finite_json(event), default=_json_default, allow_nan=False) + "\n")
            fh.flush()
        return event

    def set_status(self, state: str, message: str = "", **extra: Any) -> None:
        if state not in STATES:
            raise ValueError(f"unknown job state {state!r}")
        # pid + host: a reader on the same machine can tell a live "running" from one whose process died
        # (SIGKILL, power loss): see process_alive / status_is_stale
        write_json_atomic(self.status_path, {"state": state, "message": message, "time": time.time(),
                                             "pid": os.getpid(), "host": socket.gethostname(), **extra})

    def status(self) -> dict | None:
        return read_status(self.root)

    def cancel_requested(self) -> bool:
        return self.cancel_path.exists()

    def request_cancel(self) -> None:
        self.cancel_path.touch()


def settings_with_preset(settings: dict) -> dict:
    """job.json settings with settings["preset"] (fast | balanced | best) filled in.

    Keys the job sets explicitly win, as typed flags do for `gsgs train --preset`; the others
    take the preset's value (gsgs_engine.presets.PRESETS): iters, resolution_scale, max_side, backend,
    sh_degree (unless "auto"), prior, and prior_settings num_pseudo / rounds. The result reads
    into the same TrainConfig / PriorConfig as presets.apply_preset gives. Idempotent; a copy.
    """
    out = dict(settings)
    name = out.get("preset")
    if name in (None, "", "custom"):
        out.pop("preset", None)
        return out
    from gsgs_engine.presets import preset  # standard library only, like this module

    p = preset(name)
    for key in ("iters", "resolution_scale", "max_side", "backend", "prior"):
        out.setdefault(key, p[key])
    if p["sh_degree"] != "auto":
        out.setdefault("sh_degree", int(p["sh_degree"]))
    prior_settings = dict(out.get("prior_settings") or {})
    prior_settings.setdefault("num_pseudo", max(int(p["pseudo_views"]), 1))
    prior_settings.setdefault("rounds", int(p["rounds"]))
    out["prior_settings"] = prior_settings
    return out


def read_status(root: str | os.PathLike) -> dict | None:
    path = Path(root) / "status.json"
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        return None
    except (OSError, json.JSONDecodeError):
        return None  # being replaced right now; the next poll sees it


def process_alive(pid: int) -> bool:
    """Whether process `pid` exists on this machine (POSIX kill 0; Windows OpenProcess)."""
    if not isinstance(pid, int) or isinstance(pid, bool) or pid <= 0:
        return False
    if os.name == "nt":  # pragma: no cover - exercised on Windows only
        import ctypes

        handle = ctypes.windll.kernel32.OpenProcess(0x1000, False, pid)  # PROCESS_QUERY_LIMITED_INFORMATION
        if not handle:
            return False
        code = ctypes.c_ulong()
        ok = ctypes.windll.kernel32.GetExitCodeProcess(handle, ctypes.byref(code))
        ctypes.windll.kernel32.CloseHandle(handle)
        return bool(ok) and code.value == 259  # STILL_ACTIVE
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # exists, owned by someone else
    return True


def status_is_stale(status: dict | None) -> bool:
    """True when status.json says "running" but the process that wrote it, on this machine, is gone
    (killed with SIGKILL, a crash, a reboot): the job stopped unexpectedly and will not update again.
    A job running on another host (a cluster node) is never called stale from here."""
    if not status or status.get("state") != "running":
        return False
    if status.get("host") not in (None, socket.gethostname()) or "pid" not in status:
        return False
    return not process_alive(status.get("pid"))


class ProgressReader:
    """Incremental reader of progress.jsonl for a UI timer: each poll returns new events only.

    A partially written last line is kept back until its newline arrives.
    """

    def __init__(self, root: str | os.PathLike):
        self.path = Path(root) / "progress.jsonl"
        self._offset = 0
        self._pending = b""

    def poll(self) -> list[dict]:
        try:
            with open(self.path, "rb") as fh:
                fh.seek(self._offset)
                chunk = fh.read()
        except FileNotFoundError:
            return []
        self._offset += len(chunk)
        data = self._pending + chunk
        lines = data.split(b"\n")
        self._pending = lines.pop()  # b"" when the chunk ended with a newline
        events = []
        for line in lines:
            if line.strip():
                try:
                    events.append(json.loads(line))
                except json.JSONDecodeError:
                    continue
        return events
