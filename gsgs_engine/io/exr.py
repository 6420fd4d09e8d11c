"""OpenEXR depth maps and images, such as Blender's render passes (OpenEXR 3.x `File` API).

OpenEXR is imported inside the functions so `gsgs_engine.io` stays numpy-only on import.
Values come back as stored: EXR colour is scene-linear (no sRGB transform here), and a
Blender depth pass is planar camera z with 1e10 where the ray hit nothing. Blender 5 writes
a multilayer file as one part per pass ("ViewLayer.Combined", "ViewLayer.Depth", ...);
channels from every part are read, named as in the file ("ViewLayer.Depth.Z").
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from gsgs_engine import GsgsError

_COMPRESSIONS = ("none", "zip", "zips", "rle", "piz", "pxr24", "b44", "b44a", "dwaa", "dwab")


def read_exr_channels(path: str | os.PathLike, fill: float = 0.0) -> dict[str, np.ndarray]:
    """Every channel of every part as float32 (H, W) over the display window.

    Pixels outside a part's data window (a cropped render) are set to `fill`.
    """
    path = Path(path)
    if not path.is_file():
        raise GsgsError(f"{path}: no such EXR file; check the path")
    import OpenEXR

    try:
        exr = OpenEXR.File(str(path), separate_channels=True)
    except Exception as exc:  # the binding raises RuntimeError with the library's message
        raise GsgsError(f"{path}: cannot read it as OpenEXR ({exc}); re-export the file as .exr") from None
    channels: dict[str, np.ndarray] = {}
    with exr:
        for part in exr.parts:
            header = part.header
            for name, channel in part.channels.items():
                if channel.xSampling != 1 or channel.ySampling != 1:
                    raise GsgsError(f"{path}: channel {name!r} is subsampled ({channel.xSampling}x{channel.ySampling}); "
                                    "re-export without chroma subsampling (e.g. as RGB float)")
                if name not in channels:  # two parts with one channel name: the first part wins
                    channels[name] = _in_display_window(header, np.asarray(channel.pixels, dtype=np.float32), fill)
    if not channels:
        raise GsgsError(f"{path}: the EXR has no channels; re-export it")
    return channels


def _in_display_window(header: dict, pixels: np.ndarray, fill: float) -> np.ndarray:
    (dx0, dy0), (dx1, dy1) = (np.asarray(v).tolist() for v in header["dataWindow"])
    display = header.get("displayWindow", header["dataWindow"])
    (wx0, wy0), (wx1, wy1) = (np.asarray(v).tolist() for v in display)
    if (dx0, dy0, dx1, dy1) == (wx0, wy0, wx1, wy1):
        return np.ascontiguousarray(pixels)
    out = np.full((wy1 - wy0 + 1, wx1 - wx0 + 1), fill, np.float32)
    # the overlap of the data window with the display window, in both arrays' indices
    x0, y0, x1, y1 = max(dx0, wx0), max(dy0, wy0), min(dx1, wx1), min(dy1, wy1)
    if x0 <= x1 and y0 <= y1:
        out[y0 - wy0:y1 - wy0 + 1, x0 - wx0:x1 - wx0 + 1] = pixels[y0 - dy0:y1 - dy0 + 1, x0 - dx0:x1 - dx0 + 1]
    return out


def _layer_and_channel(name: str) -> tuple[str, str]:
    layer, _, channel = name.rpartition(".")
    return layer, channel


def pick_depth_channel(path: Path | str, names: list[str], channel: str | None = None) -> str:
    """The channel of `names` that holds depth, or GsgsError listing them.

    In order: `channel` if given; the only channel; "Z"; the channel of a layer named
    Depth (any case, e.g. "ViewLayer.Depth.Z", "Depth.Z"); a channel named "depth".
    """
    listing = ", ".join(sorted(names))
    if channel is not None:
        if channel not in names:
            raise GsgsError(f"{path}: no channel {channel!r} in the EXR (channels: {listing})")
        return channel
    if len(names) == 1:
        return names[0]
    by_rule = [
        [n for n in names if n == "Z"],
        [n for n in names if _layer_and_channel(n)[0].rpartition(".")[2].lower() == "depth"],
        [n for n in names if n.lower() == "depth"],
    ]
    for found in by_rule:
        if len(found) == 1:
            return found[0]
        if len(found) > 1:
            raise GsgsError(f"{path}: several depth channels ({', '.join(sorted(found))}), e.g. one per view layer; "
                            "pass channel=NAME to choose one")
    raise GsgsError(f"{path}: cannot tell which channel holds depth (channels: {listing}); pass channel=NAME, "
                    "or write the depth pass as a single channel named Z")


def read_exr_depth(path: str | os.PathLike, channel: str | None = None) -> np.ndarray:
    """Depth as float32 (H, W) from a depth EXR (see `pick_depth_channel` for which channel).

    A grey RGB(A) file (R == G == B, as a compositor writes a single value into colour) gives R.
    Pixels outside a cropped render's data window are +inf (nothing there).
    """
    path = Path(path)
    channels = read_exr_channels(path, fill=np.inf)
    names = list(channels)
    if channel is None and len(names) > 1 and {"R", "G", "B"} <= set(names) <= {"R", "G", "B", "A"}:
        r, g, b = channels["R"], channels["G"], channels["B"]
        if np.array_equal(r, g, equal_nan=True) and np.array_equal(r, b, equal_nan=True):
            return r
    return channels[pick_depth_channel(path, names, channel)]


def read_exr_image(path: str | os.PathLike, layer: str | None = None) -> np.ndarray:
    """Colour as float32 (H, W, 3), or (H, W, 4) when the layer has A; scene-linear as stored.

    The layer is `layer` when given ("" for bare R, G, B), else the top-level R, G, B, else a
    layer named Combined (Blender's beauty pass), else the only layer with R, G, B. A file
    with a single Y (luminance) channel reads as grey.
    """
    path = Path(path)
    channels = read_exr_channels(path)
    layers: dict[str, set[str]] = {}
    for name in channels:
        lay, ch = _layer_and_channel(name)
        layers.setdefault(lay, set()).add(ch)
    rgb_layers = [lay for lay, chans in layers.items() if {"R", "G", "B"} <= chans]
    listing = ", ".join(repr(lay) for lay in sorted(rgb_layers)) or "none"
    if layer is None:
        if "" in rgb_layers:
            layer = ""
        elif len(combined := [lay for lay in rgb_layers if lay.rpartition(".")[2] == "Combined"]) == 1:
            layer = combined[0]
        elif len(rgb_layers) == 1:
            layer = rgb_layers[0]
        elif not rgb_layers and list(channels) == ["Y"]:
            grey = channels["Y"]
            return np.repeat(grey[:, :, None], 3, axis=2)
        elif rgb_layers:
            raise GsgsError(f"{path}: several colour layers ({listing}); pass layer=NAME to choose one")
        else:
            raise GsgsError(f"{path}: no R, G, B channels in the EXR (channels: {', '.join(sorted(channels))}); "
                            "is this a depth or data pass? use read_exr_depth or read_exr_channels")
    elif layer not in rgb_layers:
        raise GsgsError(f"{path}: no colour layer {layer!r} with R, G, B (colour layers: {listing})")
    prefix = f"{layer}." if layer else ""
    order = ["R", "G", "B"] + (["A"] if "A" in layers[layer] else [])
    return np.stack([channels[prefix + c] for c in order], axis=2)


def write_exr_depth(path: str | os.PathLike, depth: np.ndarray, compression: str = "zip") -> None:
    """Write (H, W) depth as one float32 channel "Z" (lossless ZIP by default)."""
    path = Path(path)
    depth = np.asarray(depth)
    if depth.ndim == 3 and depth.shape[2] == 1:
        depth = depth[:, :, 0]
    if depth.ndim != 2 or depth.size == 0:
        raise GsgsError(f"{path}: depth must be a non-empty (H, W) array, got shape {depth.shape}")
    _write(path, {"Z": np.ascontiguousarray(depth, dtype=np.float32)}, compression)


def write_exr_image(path: str | os.PathLike, image: np.ndarray, half: bool = False, compression: str = "zip") -> None:
    """Write (H, W, 3|4) as R, G, B(, A), or (H, W) / (H, W, 1) as Y; float32, or float16 with `half`."""
    path = Path(path)
    image = np.asarray(image)
    if image.ndim == 2:
        image = image[:, :, None]
    if image.ndim != 3 or image.shape[2] not in (1, 3, 4) or image.shape[0] == 0 or image.shape[1] == 0:
        raise GsgsError(f"{path}: an EXR image must be (H, W), (H, W, 3) or (H, W, 4), got shape {image.shape}")
    names = {1: "Y", 3: "RGB", 4: "RGBA"}[image.shape[2]]
    dtype = np.float16 if half else np.float32
    _write(path, {c: np.ascontiguousarray(image[:, :, i], dtype=dtype) for i, c in enumerate(names)}, compression)


def _write(path: Path, channels: dict[str, np.ndarray], compression: str) -> None:
    import OpenEXR

    if compression not in _COMPRESSIONS:
        raise GsgsError(f"{path}: unknown EXR compression {compression!r}; use one of {', '.join(_COMPRESSIONS)}")
    member = "NO_COMPRESSION" if compression == "none" else f"{compression.upper()}_COMPRESSION"
    header = {"compression": getattr(OpenEXR.Compression, member),
              "type": OpenEXR.scanlineimage}
    path.parent.mkdir(parents=True, exist_ok=True)
    # write beside the target and rename, so a reader never sees a half-written file
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.exr")
    try:
        with OpenEXR.File(header, channels) as exr:
            exr.write(str(tmp))
        os.replace(tmp, path)
    except RuntimeError as exc:
        raise GsgsError(f"{path}: could not write the EXR ({exc}); check the folder is writable") from None
    finally:
        if tmp.exists():
            tmp.unlink()
