"""What runs on a Ray worker: one engine command in its own working folder, mirrored back as files.

Standard library only, and sent to the cluster by value (the driver registers this module with
cloudpickle), so a worker without gsgs installed still starts the actor and can say so in one
line instead of failing inside Ray's unpickler.

The driver and this actor exchange only `bytes`: tar archives built and read by the functions
below (a JSON manifest plus files). Ray hands `bytes` across unpickled (its raw-object path), and
no method here raises: a failure comes back as a manifest with an "error" entry. So nothing the
engine produces reaches the driver as a Python object; results are files, checked like local ones.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import signal
import subprocess
import sys
import tarfile
import tempfile
import traceback
from pathlib import Path

MANIFEST = "manifest.json"
APPEND_FILES = ("progress.jsonl", "log.txt")  # grow only: sent from the receiver's offset
CONSOLE = "::console"  # the engine's stdout + stderr, streamed like an append-only file
MODULES = ("gsgs_engine", "gsgs_engine.bench.accuracy_cell")  # what `python -m` may run here
MAX_MEMBER_BYTES = 8 << 30


# -- archives ----------------------------------------------------------------------------------
def skip_name(rel: str) -> bool:
    """Temp files (".ckpt.*.tmp", ".status.json.*"), hidden folders and cancel requests never travel."""
    return any(part.startswith(".") for part in Path(rel).parts) or Path(rel).name == "cancel.request"


def folder_files(root: Path, exclude: tuple[str, ...] = ()) -> dict[str, list[int]]:
    """{relative path: [size, mtime_ns]} of the regular files under `root` that travel."""
    found: dict[str, list[int]] = {}
    root = Path(root)
    if not root.is_dir():
        return found
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = sorted(d for d in dirnames if not d.startswith("."))
        for name in sorted(filenames):
            path = Path(dirpath) / name
            rel = path.relative_to(root).as_posix()
            if skip_name(rel) or rel in exclude or any(rel.startswith(e.rstrip("/") + "/") for e in exclude):
                continue
            try:
                st = path.lstat()
            except FileNotFoundError:  # removed while walking (an old checkpoint pruned)
                continue
            if path.is_symlink() or not path.is_file():
                continue
            found[rel] = [st.st_size, st.st_mtime_ns]
    return found


def _add_bytes(tar: tarfile.TarFile, name: str, data: bytes) -> None:
    info = tarfile.TarInfo(name)
    info.size = len(data)
    info.mode = 0o644
    tar.addfile(info, io.BytesIO(data))


def pack(manifest: dict, files: dict[str, bytes]) -> bytes:
    """A tar archive of a JSON manifest and files given as bytes (names are POSIX, relative)."""
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w") as tar:
        _add_bytes(tar, MANIFEST, json.dumps(manifest).encode())
        for name, data in files.items():
            _add_bytes(tar, "data/" + name, data)
    return buf.getvalue()


def pack_folder(root: Path, exclude: tuple[str, ...] = (), replace: dict[str, bytes] | None = None,
                manifest: dict | None = None) -> bytes:
    """A folder as an archive (see `pack`); `replace` swaps or adds files by relative path."""
    root = Path(root)
    files = {rel: (root / rel).read_bytes() for rel in folder_files(root, exclude)}
    files.update(replace or {})
    return pack(manifest or {}, files)


def safe_member_name(name: str) -> str:
    """`name` if it is a plain relative path inside the archive's data/ folder, else ValueError."""
    if not name.startswith("data/"):
        raise ValueError(f"unexpected archive member {name!r}")
    rel = name[len("data/"):]
    parts = Path(rel).parts
    if not rel or rel.startswith("/") or "\\" in rel or any(p in ("..", "") for p in parts) or ":" in parts[0]:
        raise ValueError(f"archive member {name!r} leaves its folder")
    return rel


def unpack(blob: bytes) -> tuple[dict, dict[str, bytes]]:
    """(manifest, {relative path: bytes}) of an archive made by `pack`; refuses links, devices,
    absolute or `..` paths and oversized members (the archive may come from another machine)."""
    files: dict[str, bytes] = {}
    manifest: dict = {}
    with tarfile.open(fileobj=io.BytesIO(blob), mode="r:") as tar:
        for member in tar.getmembers():
            if not member.isfile():
                raise ValueError(f"archive member {member.name!r} is not a regular file")
            if member.size > MAX_MEMBER_BYTES:
                raise ValueError(f"archive member {member.name!r} is {member.size} bytes")
            data = tar.extractfile(member).read()
            if member.name == MANIFEST:
                manifest = json.loads(data.decode())
                if not isinstance(manifest, dict):
                    raise ValueError("archive manifest is not a JSON object")
            else:
                files[safe_member_name(member.name)] = data
    return manifest, files


def write_file_atomic(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def unpack_into(blob: bytes, root: Path) -> dict:
    """Write an archive's files under `root`; returns its manifest."""
    manifest, files = unpack(blob)
    for rel, data in files.items():
        write_file_atomic(Path(root) / rel, data)
    return manifest


def _die_with_parent() -> None:  # pragma: no cover - runs in the child between fork and exec
    """Linux: the engine gets SIGKILL when the actor's worker process dies (a killed worker must not
    leave an orphaned training run writing into a folder nobody reads)."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except Exception:
        pass


def _error(exc: BaseException) -> bytes:
    return pack({"error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc()[-4000:]}, {})


class EngineRun:
    """A Ray actor (the driver wraps it with `ray.remote`): runs `python -m gsgs_engine ARGV` on the
    worker in a fresh folder and answers polls with what changed there."""

    def __init__(self) -> None:
        self.work = Path(tempfile.mkdtemp(prefix="gsgs_remote_"))
        self.proc: subprocess.Popen | None = None
        self.out: Path | None = None
        self.no_sync: tuple[str, ...] = ()
        self.console_path = self.work / "console.txt"

    def hello(self) -> bytes:
        """Who and where: host, pid, Python, the engine version installed on this worker."""
        try:
            import socket

            info = {"host": socket.gethostname(), "pid": os.getpid(), "python": sys.executable,
                    "work": str(self.work)}
            try:  # the node's address as Ray sees it (tests check it stays on 127.0.0.1)
                import ray

                info["node_ip"] = ray.util.get_node_ip_address()
            except Exception:
                info["node_ip"] = None
            try:
                import gsgs_engine

                info["version"] = gsgs_engine.__version__
            except Exception as exc:  # not installed on this worker
                info["version"] = None
                info["import_error"] = f"{type(exc).__name__}: {exc}"
            return pack(info, {})
        except BaseException as exc:
            return _error(exc)

    def start(self, spec: bytes, *inputs: bytes) -> bytes:
        """`spec`: JSON {argv, out, inputs: [folder names], env, no_sync, module}; `inputs`: one archive
        per folder, unpacked under the working folder. "{work}" in argv is the working folder."""
        try:
            cfg = json.loads(spec.decode())
            module = cfg.get("module", "gsgs_engine")
            if module not in MODULES:
                raise ValueError(f"module {module!r} is not one of {', '.join(MODULES)}")
            for name, blob in zip(cfg["inputs"], inputs):
                if "/" in name or name in ("", ".", ".."):
                    raise ValueError(f"bad input folder name {name!r}")
                unpack_into(blob, self.work / name)
            argv = [a.replace("{work}", str(self.work)) for a in cfg["argv"]]
            self.out = self.work / cfg["out"]
            self.out.mkdir(parents=True, exist_ok=True)
            self.no_sync = tuple(cfg.get("no_sync", ()))
            env = dict(os.environ)
            env.update({k: str(v) for k, v in (cfg.get("env") or {}).items()})
            env["PYTHONUNBUFFERED"] = "1"
            with open(self.console_path, "wb") as console:
                self.proc = subprocess.Popen([sys.executable, "-m", module, *argv], cwd=self.work,
                                             stdout=console, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                             env=env, preexec_fn=_die_with_parent if os.name == "posix" else None)
            return pack({"pid": self.proc.pid, "files": folder_files(self.out, self.no_sync)}, {})
        except BaseException as exc:
            return _error(exc)

    def poll(self, cursor: bytes) -> bytes:
        """Files under the output folder that differ from `cursor` (JSON {files: {rel: [size, mtime_ns]},
        append: {rel: offset}}), appended bytes of the grow-only files and the console, and the state."""
        try:
            cur = json.loads(cursor.decode())
            rc = self.proc.poll() if self.proc is not None else None  # read before the files: none missed
            known, offsets = cur.get("files", {}), cur.get("append", {})
            now = folder_files(self.out, self.no_sync) if self.out is not None else {}
            files: dict[str, bytes] = {}
            appended: dict[str, int] = {}
            for rel, stat in now.items():
                if rel in APPEND_FILES:
                    start = int(offsets.get(rel, 0))
                    if stat[0] != start:
                        with open(self.out / rel, "rb") as fh:
                            fh.seek(start if stat[0] > start else 0)
                            files[rel] = fh.read()
                        appended[rel] = start if stat[0] > start else 0
                elif known.get(rel) != stat:
                    try:
                        files[rel] = (self.out / rel).read_bytes()
                    except FileNotFoundError:
                        continue
            console = b""
            start = int(offsets.get(CONSOLE, 0))
            if self.console_path.is_file():
                with open(self.console_path, "rb") as fh:
                    fh.seek(start)
                    console = fh.read()
            manifest = {"running": self.proc is not None and rc is None, "returncode": rc, "files": now,
                        "appended": appended, "console_from": start, "console": console.decode("utf-8", "replace"),
                        "console_bytes": len(console)}
            return pack(manifest, files)
        except BaseException as exc:
            return _error(exc)

    def cancel(self) -> bytes:
        """Stop the engine as Ctrl-C does (SIGTERM: it finishes the step, checkpoints, says cancelled)."""
        try:
            if self.proc is not None and self.proc.poll() is None:
                self.proc.send_signal(signal.SIGTERM)
            return pack({"cancelled": True}, {})
        except BaseException as exc:
            return _error(exc)

    def close(self) -> bytes:
        """Stop the engine if it still runs and remove the working folder."""
        try:
            if self.proc is not None and self.proc.poll() is None:
                self.proc.kill()
                self.proc.wait(timeout=30)
            shutil.rmtree(self.work, ignore_errors=True)
            return pack({"closed": True}, {})
        except BaseException as exc:
            return _error(exc)
