"""The driver side of a run on a Ray cluster: send the inputs, start the engine on a worker, mirror its
folder back while it runs, forward a cancel, and retry from the last checkpoint when a worker is lost.

Ray does the scheduling (CPUs / GPUs per run), placement, retries of lost nodes' resources and the
transport; this module only decides what travels. What comes back is files: every answer of the
worker actor (gsgs_engine.cluster.worker) is a `bytes` tar archive, which Ray hands over unpickled,
checked member by member before anything is written.
"""

from __future__ import annotations

import json
import os
import socket
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from gsgs_engine import GsgsError, __version__
from gsgs_engine.cluster import worker as worker_module
from gsgs_engine.cluster.address import check_address
from gsgs_engine.cluster.worker import APPEND_FILES, CONSOLE, pack, pack_folder, unpack, write_file_atomic

INSTALL_HINT = "install Ray with `pip install 'gsgs[cluster]'` (or `pip install 'ray[default]>=2.52'`)"
POLL_S = 1.0
CANCEL_WAIT_S = 120.0  # a cancelled engine finishes its step and checkpoints; give it this long
_CONNECT_LOCK = threading.Lock()
# Ray Client (ray://) starts one server process per connecting driver on the head; when that process dies
# while starting (its log is ray_client_server_<port>.err on the head) the head answers "Starting Ray client
# server failed"; when it dies between two of the head's checks on it, the head's check raises psutil's
# ZombieProcess instead (Ray 2.60, proxier.start_specific_server; seen once in CI under load). The next
# connection gets a new process on the next port, so the driver tries again.
CLIENT_START_ATTEMPTS = 3
CLIENT_START_WAIT_S = 2.0
_CLIENT_START_FAILED = ("Starting Ray client server failed", "Proxy failed to Connect to backend",
                        "psutil.ZombieProcess")


def import_ray():
    try:
        import ray
    except ImportError as exc:
        raise GsgsError(f"--ray: Ray is not installed in {sys.executable}; {INSTALL_HINT}") from exc
    return ray


def connect(address: str):
    """ray.init(address) once per process, after the address check (nothing is sent before it)."""
    check_address(address)
    ray = import_ray()
    with _CONNECT_LOCK:
        if not ray.is_initialized():
            runtime_env = os.environ.get("GSGS_RAY_RUNTIME_ENV")
            try:
                env = json.loads(runtime_env) if runtime_env else None
            except json.JSONDecodeError as exc:
                raise GsgsError(f"GSGS_RAY_RUNTIME_ENV is not valid JSON ({exc})") from exc
            import signal

            # ray.init makes SIGTERM exit the process at once; keep gsgs's handler (SIGTERM = Ctrl-C), so a
            # terminated driver cancels its remote run and says so in status.json
            on_main = threading.current_thread() is threading.main_thread()
            previous = signal.getsignal(signal.SIGTERM) if on_main else None
            try:
                _init_with_client_retries(ray, address, env)
            except (ConnectionError, RuntimeError, ValueError) as exc:
                hint = ("; the head's Ray Client server did not start: see ray_client_server_*.err in its "
                        "session logs (/tmp/ray/session_latest/logs)" if _client_start_failed(exc) else "")
                raise GsgsError(f"--ray {address}: cannot connect to the Ray cluster ({exc}){hint}; start one with "
                                "`ray start --head --port 6380` and pass --ray HOST:6380 (docs/cluster.md)") from exc
            finally:
                if on_main and previous is not None:
                    signal.signal(signal.SIGTERM, previous)
    return ray


def _client_start_failed(exc: BaseException) -> bool:
    return any(text in str(exc) for text in _CLIENT_START_FAILED)


def _init_with_client_retries(ray, address: str, env, attempts: int = CLIENT_START_ATTEMPTS,
                              wait_s: float = CLIENT_START_WAIT_S) -> None:
    """ray.init(address); for ray:// only, a server process that died while starting is retried (a new one
    is started per connection), saying so; any other failure, or the last attempt's, is raised."""
    for attempt in range(1, attempts + 1):
        try:
            ray.init(address=address, runtime_env=env, log_to_driver=False, logging_level="ERROR",
                     configure_logging=False)
            return
        except (ConnectionError, RuntimeError) as exc:
            if not (address.startswith("ray://") and _client_start_failed(exc)) or attempt == attempts:
                raise
            print(f"gsgs: the Ray Client server at {address} failed to start (attempt {attempt}/{attempts}); "
                  f"trying again in {wait_s * attempt:.0f} s", file=sys.stderr, flush=True)
            time.sleep(wait_s * attempt)


def actor_class(ray):
    """The worker actor, sent by value so a worker without gsgs can still report that."""
    import ray.cloudpickle as cloudpickle

    cloudpickle.register_pickle_by_value(worker_module)
    return ray.remote(max_restarts=0, max_task_retries=0)(worker_module.EngineRun)


def _answer(ray, ref, what: str, timeout: float | None = None) -> tuple[dict, dict[str, bytes]]:
    blob = ray.get(ref, timeout=timeout)
    if not isinstance(blob, bytes):  # our actor returns bytes only; anything else is not ours
        raise GsgsError(f"the Ray worker's answer to {what} is not an archive ({type(blob).__name__})")
    try:
        manifest, files = unpack(blob)
    except (ValueError, OSError, json.JSONDecodeError) as exc:
        raise GsgsError(f"the Ray worker's answer to {what} is not a valid archive ({exc})") from exc
    if "error" in manifest:
        raise GsgsError(f"on the Ray worker, {what} failed: {manifest['error']}")
    return manifest, files


@dataclass
class RemoteCommand:
    """One engine command to run on the cluster.

    `argv` is what follows `python -m gsgs_engine` on the worker ("{work}" = its working folder),
    `inputs` names the folders sent along (name -> archive bytes, unpacked as {work}/name),
    `out` the working sub-folder mirrored into `local_out`; `resume_argv(has_checkpoint)` gives the
    argv of a retry after a lost worker (with the local folder's checkpoint sent back out)."""

    argv: list[str]
    inputs: dict[str, bytes]
    out: str
    local_out: Path
    resume_argv: Callable[[bool], list[str]] | None = None
    no_sync: tuple[str, ...] = ()
    num_cpus: float = 1.0
    num_gpus: float = 0.0
    env: dict = field(default_factory=dict)
    label: str = "gsgs"
    module: str = "gsgs_engine"  # what the worker runs with `python -m` (worker.MODULES)


def outgoing_state(local_out: Path) -> tuple[bytes, bool]:
    """(archive, has_checkpoint) of what a resumed remote run needs from the local run folder: its newest
    checkpoint. (progress.jsonl and log.txt stay here: the worker's start empty and are appended to ours.)"""
    local_out = Path(local_out)
    replace: dict[str, bytes] = {}
    ckpts = sorted((local_out / "checkpoints").glob("ckpt_*.safetensors")) if (local_out / "checkpoints").is_dir() else []
    if ckpts:
        replace[f"checkpoints/{ckpts[-1].name}"] = ckpts[-1].read_bytes()
    return pack({}, replace), bool(ckpts)


class Mirror:
    """The local copy of the worker's output folder, updated from poll archives."""

    def __init__(self, local_out: Path, remote_files: dict, address: str):
        self.local_out = Path(local_out)
        self.known = dict(remote_files)  # rel -> [size, mtime_ns] as the worker last sent them
        # how much of the worker's grow-only files has arrived; it is appended to ours (O_APPEND), never
        # written over: the add-on appends the driver's own output to the same log.txt
        self.offsets = {name: 0 for name in (*APPEND_FILES, CONSOLE)}
        self.address = address

    def cursor(self) -> bytes:
        return json.dumps({"files": self.known, "append": self.offsets}).encode()

    def apply(self, manifest: dict, files: dict[str, bytes]) -> str:
        """Write what arrived; returns new console text."""
        for rel, data in files.items():
            target = self.local_out / rel
            if rel in APPEND_FILES:
                start = int(manifest.get("appended", {}).get(rel, 0))
                if start != self.offsets[rel]:  # the worker's file shrank: cannot happen to a grow-only file
                    raise GsgsError(f"the Ray worker's {rel} was rewritten; the local copy keeps what came before")
                target.parent.mkdir(parents=True, exist_ok=True)
                with open(target, "ab") as fh:
                    fh.write(data)
                self.offsets[rel] = start + len(data)
            elif rel == "status.json":
                write_file_atomic(target, self._local_status(data))
            else:
                write_file_atomic(target, data)
        now = manifest.get("files", {})
        for rel in list(self.known):  # files the engine removed (older checkpoints pruned) go here too
            if rel not in now and rel.startswith("checkpoints/"):
                (self.local_out / rel).unlink(missing_ok=True)
        self.known = {rel: stat for rel, stat in now.items() if rel not in APPEND_FILES}
        self.offsets[CONSOLE] = int(manifest.get("console_from", 0)) + int(manifest.get("console_bytes", 0))
        return manifest.get("console", "")

    def _local_status(self, data: bytes) -> bytes:
        """status.json as a reader on this machine needs it: this driver's pid and host (a UI can tell
        when the driver died), the worker's under "remote"."""
        try:
            status = json.loads(data.decode())
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise GsgsError(f"the Ray worker sent an unreadable status.json ({exc})") from exc
        if not isinstance(status, dict):
            raise GsgsError("the Ray worker sent a status.json that is not a JSON object")
        status["remote"] = {"host": status.get("host"), "pid": status.get("pid"), "address": self.address}
        status["host"], status["pid"] = socket.gethostname(), os.getpid()
        return json.dumps(status, indent=2).encode()


def _lost_worker_errors(ray) -> tuple[type, ...]:
    from ray import exceptions as rex

    names = ("RayActorError", "ActorDiedError", "ActorUnavailableError", "WorkerCrashedError", "NodeDiedError",
             "ObjectLostError", "OwnerDiedError", "LocalRayletDiedError")
    return tuple(getattr(rex, n) for n in names if hasattr(rex, n))


def check_worker(hello: dict) -> None:
    if hello.get("version") is None:
        raise GsgsError(f"the Ray worker on {hello.get('host')} has no gsgs engine in {hello.get('python')} "
                        f"({hello.get('import_error')}); install gsgs {__version__} there, or set GSGS_RAY_RUNTIME_ENV "
                        "(docs/cluster.md)")
    if hello["version"] != __version__:
        raise GsgsError(f"the Ray worker on {hello.get('host')} runs gsgs {hello['version']}, this machine gsgs "
                        f"{__version__}; install the same version on both (the job folder and checkpoints are "
                        "only guaranteed between equal versions)")


def run_remote(address: str, command: RemoteCommand, echo: Callable[[str], None] | None = None,
               retries: int = 2, cancel_file: Path | None = None, poll_s: float = POLL_S,
               on_start: Callable[[dict], None] | None = None, ship_state: bool = False) -> int:
    """Run `command` on the cluster at `address` and mirror it into `command.local_out`. Returns the engine's
    exit code. Ctrl-C / SIGTERM (KeyboardInterrupt) or `cancel_file` appearing cancels the remote run; a
    lost worker is replaced up to `retries` times, resuming from the newest checkpoint that came back.
    `ship_state`: send the local folder's newest checkpoint first (a resumed run)."""
    echo = echo or (lambda text: print(text, end="", file=sys.stderr, flush=True))
    ray = connect(address)
    lost_errors = _lost_worker_errors(ray)
    engine_run = actor_class(ray)
    refs = {name: ray.put(blob) for name, blob in command.inputs.items()}  # sent once, shared by every retry
    local_out = Path(command.local_out)
    local_out.mkdir(parents=True, exist_ok=True)
    attempt = 0
    argv = list(command.argv)
    while True:
        actor = engine_run.options(num_cpus=command.num_cpus, num_gpus=command.num_gpus).remote()
        cancelled_at: float | None = None
        try:
            hello, _ = _answer(ray, actor.hello.remote(), "start-up")
            check_worker(hello)
            names = list(refs)
            blobs = [refs[n] for n in names]
            if ship_state:
                state_blob, _ = outgoing_state(local_out)
                names.append(command.out)
                blobs.append(state_blob)
            spec = json.dumps({"argv": argv, "out": command.out, "inputs": names, "env": command.env,
                               "no_sync": list(command.no_sync), "module": command.module}).encode()
            started, _ = _answer(ray, actor.start.remote(spec, *blobs), "starting the engine")
            if on_start is not None:
                on_start({**hello, "engine_pid": started.get("pid"), "attempt": attempt})
            echo(f"gsgs: running on the Ray cluster at {address}: node {hello.get('node_ip')} ({hello.get('host')}), "
                 f"worker pid {hello.get('pid')}, engine pid {started.get('pid')}, attempt {attempt + 1}\n")
            mirror = Mirror(local_out, started.get("files", {}), address)
            # the engine's messages name its folder on the worker; show the local one it is mirrored into
            remote_out = f"{hello.get('work', '')}/{command.out}" if hello.get("work") else None
            while True:
                try:
                    if cancelled_at is None and cancel_file is not None and Path(cancel_file).exists():
                        echo("gsgs: cancel requested; stopping the remote run (it saves a checkpoint)\n")
                        _answer(ray, actor.cancel.remote(), "cancel")
                        cancelled_at = time.monotonic()
                    manifest, files = _answer(ray, actor.poll.remote(mirror.cursor()), "progress", timeout=300)
                    text = mirror.apply(manifest, files)
                    if text:
                        echo(text.replace(remote_out, str(local_out)) if remote_out else text)
                    if not manifest.get("running"):
                        rc = manifest.get("returncode")
                        _close(ray, actor)
                        echo(f"gsgs: the remote run ended (exit code {rc}); its files are in {local_out}\n")
                        return int(rc if rc is not None else 1)
                    if cancelled_at is not None and time.monotonic() - cancelled_at > CANCEL_WAIT_S:
                        _close(ray, actor)
                        return 130
                    time.sleep(poll_s)
                except KeyboardInterrupt:
                    if cancelled_at is not None:  # a second interrupt: stop waiting for the checkpoint
                        ray.kill(actor)
                        raise
                    echo("gsgs: interrupted; stopping the remote run (it saves a checkpoint; "
                         "interrupt again to stop waiting)\n")
                    _answer(ray, actor.cancel.remote(), "cancel")
                    cancelled_at = time.monotonic()
        except lost_errors as exc:
            attempt += 1
            if attempt > retries:
                raise GsgsError(f"the Ray worker running {command.label} was lost {attempt} times (last: "
                                f"{type(exc).__name__}); the checkpoints that came back are in {local_out}; "
                                "run the same command with --resume to continue") from None
            _, has_ckpt = outgoing_state(local_out)
            ship_state = has_ckpt
            argv = command.resume_argv(has_ckpt) if command.resume_argv is not None else list(command.argv)
            echo(f"gsgs: lost the Ray worker ({type(exc).__name__}); starting again "
                 + ("from the last checkpoint that came back" if has_ckpt else "from the start (no checkpoint yet)")
                 + f", attempt {attempt + 1} of {retries + 1}\n")


def _close(ray, actor) -> None:
    try:
        ray.get(actor.close.remote(), timeout=60)
    except Exception:  # the folder is a temp folder; a failed clean-up must not hide the result
        pass
    try:
        ray.kill(actor)
    except Exception:
        pass


def folder_archive(root: Path, exclude: tuple[str, ...] = (), replace: dict[str, bytes] | None = None) -> bytes:
    """A local folder as an input archive (hidden files and cancel requests left out)."""
    root = Path(root)
    if not root.is_dir():
        raise GsgsError(f"{root}: folder not found; nothing to send to the cluster")
    return pack_folder(root, exclude, replace)
