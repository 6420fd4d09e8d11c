"""Run engine jobs in a child process and watch them through the job folder.

The add-on never imports torch: it starts `python -m gsgs_engine run-job DIR` with an
argument list (no shell), sends stdout/stderr to DIR/log.txt, and learns everything else
from progress.jsonl and status.json. In the UI a bpy.app.timers callback polls; headless
callers (bpy module, `blender --background`) call `wait()` instead.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from gsgs_engine import GsgsError
from gsgs_engine.job import STATES, Job, ProgressReader, read_status, status_is_stale

CANCEL_GRACE_S = 10.0  # the engine checks cancel.request between steps; then we terminate
KILL_GRACE_S = 5.0  # after terminate(), kill() if the process still has not exited
TIMER_INTERVAL_S = 0.5
FINAL_STATES = ("ok", "error", "cancelled")


def engine_command(python: str, job_dir: str | os.PathLike) -> list[str]:
    return [python, "-m", "gsgs_engine", "run-job", str(job_dir)]


def engine_env(engine_root: str | os.PathLike | None = None, extra: dict | None = None) -> dict:
    """Environment of the child: the engine's source folder first on PYTHONPATH (for a checkout), plus
    `extra` (e.g. the Ray token of a cluster job)."""
    env = dict(os.environ)
    env.update(extra or {})
    # Blender sets these for its own bundled Python; they would break another interpreter.
    for key in ("PYTHONHOME", "PYTHONNOUSERSITE"):
        env.pop(key, None)
    if engine_root:
        parts = [str(engine_root)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p]
        env["PYTHONPATH"] = os.pathsep.join(parts)
    env.setdefault("PYTHONUNBUFFERED", "1")
    return env


def log_tail(job_dir: str | os.PathLike, lines: int = 15, max_bytes: int = 16384) -> str:
    path = Path(job_dir) / "log.txt"
    try:
        with open(path, "rb") as fh:
            fh.seek(0, os.SEEK_END)
            size = fh.tell()
            fh.seek(max(0, size - max_bytes))
            text = fh.read().decode("utf-8", errors="replace")
    except FileNotFoundError:
        return ""
    return "\n".join(text.splitlines()[-lines:])


def stopped_unexpectedly(status: dict) -> str:
    """The message for a "running" status whose process is gone (status_is_stale)."""
    return (f"stopped unexpectedly: the engine process (pid {status.get('pid')}) is gone without finishing "
            "(killed or crashed); start the job again to resume from its last checkpoint")


def format_losses(losses: dict | None) -> str:
    if not losses:
        return ""
    parts = []
    for key, value in losses.items():
        parts.append(f"{key} {value:.4g}" if isinstance(value, (int, float)) else f"{key} {value}")
    return ", ".join(parts)


def format_eta(eta_s: float | None) -> str:
    if eta_s is None or eta_s < 0:
        return ""
    eta_s = int(round(eta_s))
    h, rem = divmod(eta_s, 3600)
    m, s = divmod(rem, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


@dataclass
class JobRun:
    """One job folder and (when this session started it) its child process."""

    job_dir: Path
    process: subprocess.Popen | None = None
    state: str = "running"  # running | ok | error | cancelled
    message: str = ""
    last_event: dict | None = None
    events: int = 0
    cancel_at: float | None = None
    terminate_at: float | None = None
    cancel_grace: float | None = None  # None: CANCEL_GRACE_S; longer for a cluster job (the remote run checkpoints)
    on_finish: list[Callable[["JobRun"], None]] = field(default_factory=list)
    finished_handled: bool = False
    _reader: ProgressReader | None = None

    @property
    def cancel_grace_s(self) -> float:
        return CANCEL_GRACE_S if self.cancel_grace is None else self.cancel_grace

    def __post_init__(self) -> None:
        self.job_dir = Path(self.job_dir)
        self._reader = ProgressReader(self.job_dir)

    # -- reading ------------------------------------------------------------------------
    @property
    def finished(self) -> bool:
        return self.state in FINAL_STATES

    @property
    def progress(self) -> float:
        ev = self.last_event or {}
        total = ev.get("total") or 0
        return min(1.0, max(0.0, ev.get("step", 0) / total)) if total else 0.0

    @property
    def phase(self) -> str:
        return (self.last_event or {}).get("phase", "starting" if self.state == "running" else self.state)

    def summary(self) -> dict:
        ev = self.last_event or {}
        return {"state": self.state, "message": self.message or ev.get("message", ""), "phase": self.phase,
                "progress": self.progress, "step": ev.get("step", 0), "total": ev.get("total", 0),
                "losses": format_losses(ev.get("losses")), "eta": format_eta(ev.get("eta_s"))}

    def poll(self) -> list[dict]:
        """Read new progress events and settle the state when the process has exited."""
        new = self._reader.poll()
        if new:
            self.last_event = new[-1]
            self.events += len(new)
        if self.finished:
            return new
        now = time.monotonic()
        if self.process is None:
            status = read_status(self.job_dir) or {}
            if status.get("state") in FINAL_STATES:
                self._settle(status.get("state"), status.get("message", ""))
            elif status_is_stale(status):
                self._settle("error", stopped_unexpectedly(status))
            return new
        rc = self.process.poll()
        if rc is None:
            if self.cancel_at is not None and self.terminate_at is None and now - self.cancel_at > self.cancel_grace_s:
                self.process.terminate()
                self.terminate_at = now
            elif self.terminate_at is not None and now - self.terminate_at > KILL_GRACE_S:
                self.process.kill()
            return new
        last = self._reader.poll()  # lines written just before exit
        if last:
            self.events += len(last)
            new += last
        if new:
            self.last_event = new[-1]
        status = read_status(self.job_dir) or {}
        state, message = status.get("state"), status.get("message", "")
        if state in FINAL_STATES:
            self._settle(state, message)
        elif self.cancel_at is not None:
            Job(root=self.job_dir).set_status("cancelled", "cancelled: the engine was stopped after a grace period")
            self._settle("cancelled", "cancelled: the engine was stopped after a grace period")
        else:
            tail = log_tail(self.job_dir, lines=3).strip().replace("\n", " | ")
            msg = f"the engine exited with code {rc} without finishing the job; log.txt ends: {tail or '(empty)'}"
            Job(root=self.job_dir).set_status("error", msg)
            self._settle("error", msg)
        return new

    def _settle(self, state: str, message: str) -> None:
        self.state, self.message = state, message

    # -- control ------------------------------------------------------------------------
    def request_cancel(self) -> None:
        """Ask the engine to stop at its next step; terminate() follows after the grace period."""
        if self.finished:
            return
        # The engine sees cancel.request between steps; a process we started is also
        # terminated by poll() if it has not stopped after the grace period.
        Job(root=self.job_dir).request_cancel()
        self.cancel_at = time.monotonic()

    def wait(self, timeout: float | None = None, interval: float = 0.2,
             on_events: Callable[[list[dict]], None] | None = None) -> str:
        """Poll until the job finishes (headless use). Returns the final state."""
        start = time.monotonic()
        while True:
            events = self.poll()
            if events and on_events is not None:
                on_events(events)
            if self.finished:
                return self.state
            if timeout is not None and time.monotonic() - start > timeout:
                # Never leave an orphaned engine behind: cancel, and terminate after the grace period.
                self.request_cancel()
                give_up = time.monotonic() + self.cancel_grace_s + KILL_GRACE_S + 5.0
                while not self.finished and time.monotonic() < give_up:
                    self.poll()
                    time.sleep(interval)
                raise GsgsError(f"{self.job_dir}: job still running after {timeout:.0f} s, so it was "
                                f"{self.state}; see {self.job_dir / 'log.txt'}")
            time.sleep(interval)


# -- starting jobs --------------------------------------------------------------------------------
RUNS: dict[str, JobRun] = {}


def start(job_dir: str | os.PathLike, python: str, engine_root: str | os.PathLike | None = None,
          on_finish: Callable[[JobRun], None] | None = None, use_timer: bool | None = None,
          command: list[str] | None = None, extra_args: list[str] | None = None, extra_env: dict | None = None,
          cancel_grace_s: float | None = None) -> JobRun:
    """Start `python -m gsgs_engine run-job job_dir [extra_args]` (or `command`) in the background and
    register it."""
    job_dir = Path(job_dir).resolve()
    Job.open(job_dir)  # validates job.json before a process is spent on it
    key = str(job_dir)
    current = RUNS.get(key)
    if current is not None and not current.finished:
        raise GsgsError(f"{job_dir}: this job is already running; cancel it first")
    if not python:
        raise GsgsError("no engine Python interpreter set; set it in the GS-GS add-on preferences")
    # A resumed job starts clean: an old cancel request or final status must not end it at once.
    for stale in (job_dir / "cancel.request", job_dir / "status.json"):
        if stale.exists():
            stale.unlink()
    argv = list(command) if command is not None else engine_command(python, job_dir) + list(extra_args or [])
    with open(job_dir / "log.txt", "ab") as log:
        log.write(f"\n== gsgs: starting {' '.join(argv)} at {time.ctime()}\n".encode())
        log.flush()
        try:
            process = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT,
                                       stdin=subprocess.DEVNULL, cwd=str(engine_root or job_dir),
                                       env=engine_env(engine_root, extra_env))
        except OSError as exc:
            raise GsgsError(f"cannot start the engine interpreter {python!r} ({exc}); "
                            "set a working Python in the GS-GS add-on preferences") from exc
    run = JobRun(job_dir=job_dir, process=process, cancel_grace=cancel_grace_s)
    # Skip events a previous run of this folder already wrote; show only this run's.
    run._reader.poll()
    run.last_event = None
    if on_finish is not None:
        run.on_finish.append(on_finish)
    RUNS[key] = run
    if use_timer is None:
        use_timer = ui_available()
    if use_timer:
        ensure_timer()
    return run


def attach(job_dir: str | os.PathLike) -> JobRun:
    """The run of a job folder: the live one, or one read from the folder (a job started by an
    earlier session or another machine). A folder whose status is "running" is followed through
    its files; cancel then works through cancel.request only."""
    key = str(Path(job_dir).resolve())
    run = RUNS.get(key)
    if run is None:
        run = JobRun(job_dir=Path(key))
        status = read_status(key) or {}
        run.state = status.get("state") if status.get("state") in STATES else "unknown"
        run.message = status.get("message", "")
        if status_is_stale(status):
            run.state, run.message = "error", stopped_unexpectedly(status)
        run.finished_handled = True  # its result was handled (or is imported on request)
        events = run._reader.poll()
        run.last_event = events[-1] if events else None
        RUNS[key] = run
        if run.state == "running" and ui_available():
            ensure_timer()
    return run


def ui_available() -> bool:
    """True inside an interactive Blender (timers fire); False for the bpy module / --background."""
    try:
        import bpy
    except ImportError:
        return False
    return not bpy.app.background


def tick_all() -> bool:
    """Poll every live run once; fire on_finish callbacks. Returns True while any still runs."""
    alive = False
    for run in list(RUNS.values()):
        if run.state not in ("running",):
            if run.finished and not run.finished_handled:
                _finish(run)
            continue
        run.poll()
        if run.finished:
            _finish(run)
        else:
            alive = True
    return alive


def _finish(run: JobRun) -> None:
    run.finished_handled = True
    for callback in run.on_finish:
        try:
            callback(run)
        except Exception as exc:  # a failed import must not kill the timer for other jobs
            run.state, run.message = "error", f"{type(exc).__name__} while loading the result: {exc}"
            print(f"gsgs: {run.job_dir}: {run.message}", file=sys.stderr)


def _timer() -> float | None:
    alive = tick_all()
    _redraw()
    return TIMER_INTERVAL_S if alive else None


def ensure_timer() -> None:
    import bpy

    if not bpy.app.timers.is_registered(_timer):
        bpy.app.timers.register(_timer, first_interval=TIMER_INTERVAL_S, persistent=True)


def stop_timer() -> None:
    try:
        import bpy
    except ImportError:
        return
    if bpy.app.timers.is_registered(_timer):
        bpy.app.timers.unregister(_timer)


def _redraw() -> None:
    import bpy

    wm = bpy.context.window_manager
    for window in getattr(wm, "windows", []):
        for area in window.screen.areas:
            if area.type == "VIEW_3D":
                area.tag_redraw()


def wait_for(run: JobRun, timeout: float | None = None, echo: bool = True, echo_every_s: float = 2.0) -> str:
    """Headless: block until `run` finishes, printing a progress line at most every `echo_every_s`
    seconds (and at every phase change); then fire the on_finish callbacks."""
    last = {"time": 0.0, "phase": None}

    def show(events: list[dict]) -> None:
        ev = events[-1]
        now = time.monotonic()
        if not echo or (ev.get("phase") == last["phase"] and now - last["time"] < echo_every_s
                        and ev.get("step") != ev.get("total")):
            return
        last.update(time=now, phase=ev.get("phase"))
        total = f"/{ev['total']}" if ev.get("total") else ""
        eta = format_eta(ev.get("eta_s"))
        print(f"gsgs [{ev.get('phase', '')}] {ev.get('step', 0)}{total} {format_losses(ev.get('losses'))} "
              f"{ev.get('message', '')}{'  ETA ' + eta if eta else ''}".rstrip(), flush=True)

    run.wait(timeout=timeout, on_events=show)
    if not run.finished_handled:
        _finish(run)
    return run.state
