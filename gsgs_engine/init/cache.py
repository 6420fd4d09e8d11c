"""The initialisation's slow, deterministic results kept across jobs.

An artist trains the same photos more than once: a preset tried after another, the pseudo path edited, a cancelled
run started again. Each time the plan triangulated the training views (pycolmap SIFT in a child process: 4-12 s on
the protocol scenes) and the dense initialisation swept them (5-7 s), computing what they had computed before, and on
an object orbit those two steps are about half of the `fast` preset's wait (docs/speed.md, "Session 42").

An entry is stored under a key made of everything its computation reads: the exact pixels and cameras, its settings,
the source files of the code that computes it and the versions of the libraries it calls. So a hit returns what the
computation would return here, and any change -- a pixel, a setting, an edited source file, another pycolmap -- is
a miss. Where: $GSGS_INIT_CACHE (a folder; "off" turns the cache off), else $XDG_CACHE_HOME/gsgs/init, else
~/.cache/gsgs/init. Entries are written whole (a temporary file renamed over the entry), the newest MAX_ENTRIES of
each kind are kept, and an entry that cannot be read is a miss that the next store replaces.
"""

from __future__ import annotations

import functools
import hashlib
import io
import json
import logging
import os
import sys
import tempfile
import zipfile
from pathlib import Path

import numpy as np

from gsgs_engine import user_cache_dir

log = logging.getLogger("gsgs.init.cache")

CACHE_ENV = "GSGS_INIT_CACHE"
FORMAT = 1  # bump when an entry's layout changes
MAX_ENTRIES = 32  # of each kind; measured: a dense initialisation of 16-20k points 0.4-0.5 MB, a triangulation 80-100 kB


def cache_root() -> Path | None:
    """The cache's folder, or None when $GSGS_INIT_CACHE is "off"."""
    setting = os.environ.get(CACHE_ENV, "").strip()
    if setting.lower() in ("off", "0", "none", "false"):
        return None
    if setting:
        return Path(setting).expanduser()
    return user_cache_dir("init")


@functools.lru_cache(maxsize=None)
def source_digest(*module_names: str) -> str:
    """sha256 over the source files of the named (imported) modules: an edit of the code is a new key."""
    h = hashlib.sha256()
    for name in module_names:
        h.update(name.encode())
        h.update(Path(sys.modules[name].__file__).read_bytes())
    return h.hexdigest()


@functools.lru_cache(maxsize=None)
def package_versions(*names: str) -> tuple[str, ...]:
    """The installed versions of the named distributions (read from their metadata, nothing imported)."""
    from importlib import metadata

    out = []
    for name in names:
        try:
            out.append(f"{name} {metadata.version(name)}")
        except metadata.PackageNotFoundError:
            out.append(f"{name} -")
    return tuple(out)


def key(*parts) -> str:
    """A hex digest of the parts: bytes, numpy arrays (dtype, shape and bytes), or anything JSON can write."""
    h = hashlib.sha256(f"gsgs-init-cache {FORMAT}".encode())
    for part in parts:
        if isinstance(part, np.ndarray):
            arr = np.ascontiguousarray(part)
            h.update(f"array {arr.dtype.str} {arr.shape}".encode())
            h.update(arr.tobytes())
        elif isinstance(part, (bytes, bytearray)):
            h.update(b"bytes %d " % len(part))
            h.update(part)
        else:
            h.update(("json " + json.dumps(part, sort_keys=True, default=str)).encode())
    return h.hexdigest()


def _entry(kind: str, digest: str, suffix: str) -> Path | None:
    root = cache_root()
    return None if root is None else root / kind / f"{digest}{suffix}"


def _read(kind: str, digest: str, suffix: str) -> bytes | None:
    path = _entry(kind, digest, suffix)
    if path is None or not path.is_file():
        return None
    try:
        data = path.read_bytes()
    except OSError as exc:
        log.warning("init cache: cannot read %s (%s); computing it again", path, exc)
        return None
    try:
        os.utime(path)  # the most recently used entries are the ones kept
    except OSError:
        pass  # a read-only cache still serves its entries
    return data


def _write(kind: str, digest: str, suffix: str, data: bytes) -> None:
    path = _entry(kind, digest, suffix)
    if path is None:
        return
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=suffix)
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.write(data)
            os.replace(tmp, path)
        finally:
            if os.path.exists(tmp):
                os.remove(tmp)
        entries = sorted((p for p in path.parent.iterdir() if p.suffix == suffix and not p.name.startswith(".")),
                         key=lambda p: p.stat().st_mtime, reverse=True)
        for old in entries[MAX_ENTRIES:]:
            old.unlink(missing_ok=True)
    except OSError as exc:  # a full or read-only disk costs the next run the time, nothing else
        log.warning("init cache: cannot write %s (%s); set %s=off to stop trying", path, exc, CACHE_ENV)


def load_json(kind: str, digest: str):
    data = _read(kind, digest, ".json")
    if data is None:
        return None
    try:
        return json.loads(data)
    except ValueError as exc:
        log.warning("init cache: %s/%s.json is damaged (%s); computing it again", kind, digest, exc)
        return None


def _plain(o):
    """json.dumps' fallback: numpy arrays as lists, numpy scalars as numbers (float32 values round-trip exactly)."""
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"{type(o).__name__} is not stored in the init cache")


def store_json(kind: str, digest: str, value) -> None:
    """Store `value` (JSON with numpy arrays and scalars in it). A value that cannot be written is not stored: the
    cache never stops the job it serves."""
    try:
        data = json.dumps(value, default=_plain).encode()
    except (TypeError, ValueError) as exc:
        log.warning("init cache: %s entry not stored (%s)", kind, exc)
        return
    _write(kind, digest, ".json", data)


def load_arrays(kind: str, digest: str) -> tuple[dict[str, np.ndarray], dict] | None:
    """(arrays, meta) stored by store_arrays, or None."""
    data = _read(kind, digest, ".npz")
    if data is None:
        return None
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as npz:
            arrays = {name: npz[name] for name in npz.files if name != "meta"}
            meta = json.loads(bytes(npz["meta"]).decode())
        return arrays, meta
    except (ValueError, KeyError, OSError, zipfile.BadZipFile) as exc:
        log.warning("init cache: %s/%s.npz is damaged (%s); computing it again", kind, digest, exc)
        return None


def store_arrays(kind: str, digest: str, arrays: dict[str, np.ndarray], meta: dict) -> None:
    buf = io.BytesIO()
    try:
        text = json.dumps(meta, default=_plain)
        np.savez(buf, meta=np.frombuffer(text.encode(), dtype=np.uint8), **arrays)
    except (TypeError, ValueError) as exc:
        log.warning("init cache: %s entry not stored (%s)", kind, exc)
        return
    _write(kind, digest, ".npz", buf.getvalue())
