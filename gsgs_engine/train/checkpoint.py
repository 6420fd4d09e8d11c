"""Training checkpoints: written atomically (temp file + rename), the newest few kept.

A checkpoint holds everything a resumed run needs to continue the same schedule: step,
model, Adam state, densification statistics, RNG states, the plan and counters.

The file format cannot run code when it is read. A job folder moves between machines and
people (DESIGN.md), so a checkpoint is untrusted input: its tensors are stored with
safetensors (raw little-endian buffers and a JSON header) and everything else (numbers,
strings, lists, dicts, the numpy RNG state) as JSON in the safetensors metadata. Reading it
never unpickles. A pickle in the checkpoints folder (an older gsgs's `ckpt_*.pt`, or a
planted file) is refused by name, never opened by torch.load.
"""

from __future__ import annotations

import json
import math
import os
import re
import tempfile
from pathlib import Path

import torch

from gsgs_engine import GsgsError
from gsgs_engine.job import output_file_mode

SUFFIX = ".safetensors"
_NAME = re.compile(r"^ckpt_(\d{7})\.safetensors$")
_PICKLED = re.compile(r"^ckpt_(\d{7})\.(pt|pth|pkl|ckpt)$")
_STATE_KEY = "gsgs_state"
KEEP = 2
START_AFRESH = ("start afresh: `gsgs train ... --overwrite`, or for a job folder delete its checkpoints/ folder "
                "and run the job again")


def checkpoint_path(directory: Path, step: int) -> Path:
    return Path(directory) / f"ckpt_{step:07d}{SUFFIX}"


def list_checkpoints(directory: Path) -> list[tuple[int, Path]]:
    """(step, path) of the checkpoints in `directory`, oldest first.

    A pickled checkpoint there is an error naming it (it is never loaded: unpickling runs code)."""
    directory = Path(directory)
    if not directory.is_dir():
        return []
    found = []
    for entry in directory.iterdir():
        m = _NAME.match(entry.name)
        if m:
            found.append((int(m.group(1)), entry))
        elif _PICKLED.match(entry.name):
            raise GsgsError(f"{entry}: a pickled checkpoint (from an older gsgs or another tool); it was not loaded "
                            "(gsgs never unpickles: opening a pickle can run arbitrary code). Delete the file; to "
                            + START_AFRESH)
    return sorted(found)


def latest_checkpoint(directory: Path) -> Path | None:
    found = list_checkpoints(directory)
    return found[-1][1] if found else None


def to_cpu(obj):
    """`obj` with every tensor in its dicts, lists and tuples moved to the CPU (CPU tensors kept as they are)."""
    if isinstance(obj, torch.Tensor):
        return obj.detach().cpu() if obj.device.type != "cpu" else obj
    if isinstance(obj, dict):
        return {k: to_cpu(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(to_cpu(v) for v in obj)
    return obj


# -- state <-> (tensors, JSON) -------------------------------------------------------------------
def _encode(obj, tensors: dict):
    """A JSON-able mirror of `obj`; tensors go to `tensors` and leave a {"__t": key} marker."""
    if isinstance(obj, torch.Tensor):
        key = f"t{len(tensors)}"
        t = obj.detach().cpu()
        whole = t.is_contiguous() and t.storage_offset() == 0 and \
            t.untyped_storage().nbytes() == t.numel() * t.element_size()
        tensors[key] = t if whole and not any(t.untyped_storage().data_ptr() == o.untyped_storage().data_ptr()
                                              for o in tensors.values() if o.numel()) else t.clone()
        # (a view, or a second reference to one buffer, gets its own copy: safetensors refuses shared memory)
        return {"__t": key}
    if isinstance(obj, bool) or obj is None or isinstance(obj, (int, str)):
        return obj
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else {"__f": repr(obj)}
    if hasattr(obj, "item") and getattr(obj, "shape", None) == ():  # a numpy scalar
        return _encode(obj.item(), tensors)
    if isinstance(obj, tuple):
        return {"__tuple": [_encode(v, tensors) for v in obj]}
    if isinstance(obj, list):
        return [_encode(v, tensors) for v in obj]
    if isinstance(obj, dict):
        if all(isinstance(k, str) and not k.startswith("__") for k in obj):
            return {k: _encode(v, tensors) for k, v in obj.items()}
        return {"__items": [[_encode(k, tensors), _encode(v, tensors)] for k, v in obj.items()]}
    raise TypeError(f"checkpoint state cannot hold a {type(obj).__name__}")


def _decode(obj, tensors: dict, where: Path):
    if isinstance(obj, list):
        return [_decode(v, tensors, where) for v in obj]
    if not isinstance(obj, dict):
        return obj
    if "__t" in obj:
        try:
            return tensors[obj["__t"]]
        except (KeyError, TypeError):
            raise GsgsError(f"{where}: damaged checkpoint (tensor {obj['__t']!r} is missing)") from None
    if "__f" in obj:
        return float(obj["__f"])  # only "nan", "inf", "-inf" are written
    if "__tuple" in obj:
        return tuple(_decode(v, tensors, where) for v in obj["__tuple"])
    if "__items" in obj:
        out = {}
        for k, v in obj["__items"]:
            k = _decode(k, tensors, where)
            out[tuple(k) if isinstance(k, list) else k] = _decode(v, tensors, where)
        return out
    return {k: _decode(v, tensors, where) for k, v in obj.items()}


def encode_state(state: dict) -> bytes:
    """The bytes of a checkpoint file holding `state`."""
    from safetensors.torch import save

    tensors: dict = {}
    meta = _encode(to_cpu(state), tensors)
    return save(tensors, metadata={_STATE_KEY: json.dumps(meta, allow_nan=False)})


def decode_state(data: bytes, where: Path) -> dict:
    """`state` back from encode_state's bytes; anything else is a GsgsError naming `where`."""
    from safetensors import SafetensorError
    from safetensors.torch import load

    # A safetensors file starts with its JSON header's length (8 bytes, little-endian), then "{". That length
    # can begin with any byte, 0x80 or "PK" too, so the pickle / zip signatures count only when this fails.
    looks_safetensors = (len(data) > 8 and data[8:9] == b"{"
                         and int.from_bytes(data[:8], "little") <= len(data) - 8)
    if not looks_safetensors and (len(data) < 8 or data[:1] == b"\x80"):  # pickle protocol 2+ starts with 0x80
        kind = "a pickle" if data[:1] == b"\x80" else "too short"
        raise GsgsError(f"{where}: not a gsgs checkpoint ({kind}); it was not loaded (gsgs never unpickles). "
                        f"Delete it; to resume from the previous checkpoint run again, or {START_AFRESH}")
    if not looks_safetensors and data[:2] == b"PK":  # torch.save's zip archive
        raise GsgsError(f"{where}: a torch.save (pickle) archive, not a gsgs checkpoint; it was not loaded (gsgs never "
                        f"unpickles). Delete it; to {START_AFRESH}")
    try:
        header_len = int.from_bytes(data[:8], "little")
        if header_len > len(data) - 8:
            raise ValueError(f"header of {header_len} bytes in a {len(data)}-byte file")
        header = json.loads(data[8:8 + header_len])
        meta_text = (header.get("__metadata__") or {}).get(_STATE_KEY)
        if meta_text is None:
            raise ValueError("no gsgs state in the header")
        tensors = load(data)
        meta = json.loads(meta_text)
    except (ValueError, SafetensorError, UnicodeDecodeError, AttributeError) as exc:
        raise GsgsError(f"{where}: unreadable checkpoint ({type(exc).__name__}: {exc}); delete it to resume from the "
                        f"previous one, or {START_AFRESH}") from None
    state = _decode(meta, tensors, where)
    if not isinstance(state, dict):
        raise GsgsError(f"{where}: damaged checkpoint (its state is not an object); delete it")
    return state


# -- files -------------------------------------------------------------------------------------
def save_checkpoint(directory: Path, step: int, state: dict, keep: int = KEEP) -> Path:
    """Write `state` for `step`; a crash mid-write leaves the previous checkpoint intact.

    Tensors are written as CPU tensors, so a checkpoint made on a GPU resumes on a CPU-only
    machine (and the other way round: the trainer moves what it loads to its own device).
    """
    data = encode_state(state)
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    path = checkpoint_path(directory, step)
    fd, tmp = tempfile.mkstemp(prefix=".ckpt.", suffix=".tmp", dir=directory)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, output_file_mode())  # mkstemp makes 0600; a checkpoint is an ordinary output file
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    for _, old in list_checkpoints(directory)[:-keep]:
        old.unlink(missing_ok=True)
    return path


def load_checkpoint(path: Path) -> dict:
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise GsgsError(f"{path}: cannot read the checkpoint ({exc.strerror or exc})") from None
    return decode_state(data, path)
