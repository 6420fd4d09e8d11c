"""EXR depth and image files: round trips, Blender's multilayer layouts, channel choice, errors."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from gsgs_engine import GsgsError
from gsgs_engine.io.exr import read_exr_channels, read_exr_depth, read_exr_image, write_exr_depth, write_exr_image

OpenEXR = pytest.importorskip("OpenEXR")
H, W = 6, 8


def ramp(seed: int, shape=(H, W)) -> np.ndarray:
    return np.random.default_rng(seed).uniform(0.5, 20.0, size=shape).astype(np.float32)


def write_raw(path, channels: dict[str, np.ndarray], header=None) -> None:
    with OpenEXR.File(header or {}, channels) as f:
        f.write(str(path))


def blender5_multilayer(path, depth: np.ndarray, rgba: np.ndarray) -> None:
    """The layout Blender 5.0.1 writes for a multilayer render (one part per pass; checked by rendering one)."""
    layers = {
        "ViewLayer.Combined": {f"ViewLayer.Combined.{c}": rgba[:, :, i].copy() for i, c in enumerate("RGBA")},
        "ViewLayer.Depth": {"ViewLayer.Depth.Z": depth},
        "ViewLayer.Normal": {f"ViewLayer.Normal.{c}": ramp(9 + i) for i, c in enumerate("XYZ")},
        "ViewLayer.Noisy Image": {f"ViewLayer.Noisy Image.{c}": ramp(20 + i) for i, c in enumerate("RGBA")},
    }
    parts = [OpenEXR.Part({"type": OpenEXR.scanlineimage, "compression": OpenEXR.ZIP_COMPRESSION, "name": name},
                          channels, name) for name, channels in layers.items()]
    with OpenEXR.File(parts) as f:
        f.write(str(path))


def test_depth_round_trip_is_exact_with_channel_z(tmp_path):
    depth = ramp(0)
    depth[0, 0], depth[1, 1] = np.inf, 1e10  # Blender's "nothing hit" values survive
    write_exr_depth(tmp_path / "d.exr", depth[:, :, None].astype(np.float64))
    back = read_exr_depth(tmp_path / "d.exr")
    assert back.dtype == np.float32 and back.shape == (H, W) and np.array_equal(back, depth)
    assert list(read_exr_channels(tmp_path / "d.exr")) == ["Z"]
    write_exr_depth(tmp_path / "p.exr", depth, compression="piz")
    assert np.array_equal(read_exr_depth(tmp_path / "p.exr"), depth)


def test_blender5_multipart_multilayer(tmp_path):
    depth, rgba = ramp(1), np.random.default_rng(2).random((H, W, 4)).astype(np.float32)
    blender5_multilayer(tmp_path / "ml.exr", depth, rgba)
    assert np.array_equal(read_exr_depth(tmp_path / "ml.exr"), depth)  # not Normal.Z
    image = read_exr_image(tmp_path / "ml.exr")  # Combined, not the Noisy Image layer
    assert image.shape == (H, W, 4) and np.array_equal(image, rgba)
    noisy = read_exr_image(tmp_path / "ml.exr", layer="ViewLayer.Noisy Image")
    assert np.array_equal(noisy[:, :, 0], ramp(20))
    assert np.array_equal(read_exr_depth(tmp_path / "ml.exr", channel="ViewLayer.Normal.Z"), ramp(11))


def test_single_part_layers_and_single_channels(tmp_path):
    depth = ramp(3)
    write_raw(tmp_path / "old.exr", {"RenderLayer.Combined.R": ramp(4), "RenderLayer.Combined.G": ramp(5),
                                     "RenderLayer.Combined.B": ramp(6), "RenderLayer.Depth.Z": depth})
    assert np.array_equal(read_exr_depth(tmp_path / "old.exr"), depth)
    assert read_exr_image(tmp_path / "old.exr").shape == (H, W, 3)
    write_raw(tmp_path / "dz.exr", {"Depth.Z": depth, "Depth.V": ramp(1)})  # two channels in one Depth layer
    with pytest.raises(GsgsError, match="several depth channels"):
        read_exr_depth(tmp_path / "dz.exr")
    for name in ("V", "R", "depth"):  # the compositor's value output, a red-only file, other tools
        write_raw(tmp_path / f"{name}.exr", {name: depth})
        assert np.array_equal(read_exr_depth(tmp_path / f"{name}.exr"), depth)
    write_raw(tmp_path / "grey.exr", {"R": depth, "G": depth, "B": depth, "A": np.ones((H, W), np.float32)})
    assert np.array_equal(read_exr_depth(tmp_path / "grey.exr"), depth)
    write_raw(tmp_path / "half.exr", {"Z": depth.astype(np.float16)})
    back = read_exr_depth(tmp_path / "half.exr")
    assert back.dtype == np.float32 and np.array_equal(back, depth.astype(np.float16).astype(np.float32))


def test_ambiguous_depth_lists_channels(tmp_path):
    write_raw(tmp_path / "rgb.exr", {"R": ramp(1), "G": ramp(2), "B": ramp(3)})
    with pytest.raises(GsgsError, match=r"rgb\.exr: cannot tell which channel holds depth \(channels: B, G, R\)"):
        read_exr_depth(tmp_path / "rgb.exr")
    write_raw(tmp_path / "two.exr", {"A.Depth.Z": ramp(1), "B.Depth.Z": ramp(2)})
    with pytest.raises(GsgsError, match="several depth channels .*pass channel=NAME"):
        read_exr_depth(tmp_path / "two.exr")
    assert np.array_equal(read_exr_depth(tmp_path / "two.exr", channel="B.Depth.Z"), ramp(2))
    with pytest.raises(GsgsError, match="no channel 'Z' in the EXR"):
        read_exr_depth(tmp_path / "two.exr", channel="Z")


def test_image_round_trip_float_half_and_grey(tmp_path):
    rgb = np.random.default_rng(4).random((H, W, 3)).astype(np.float32) * 4.0  # linear HDR values above 1
    write_exr_image(tmp_path / "rgb.exr", rgb)
    assert np.array_equal(read_exr_image(tmp_path / "rgb.exr"), rgb)
    rgba = np.concatenate([rgb, np.full((H, W, 1), 0.5, np.float32)], axis=2)
    write_exr_image(tmp_path / "rgba.exr", rgba, half=True)
    back = read_exr_image(tmp_path / "rgba.exr")
    assert back.dtype == np.float32 and back.shape == (H, W, 4)
    assert np.array_equal(back, rgba.astype(np.float16).astype(np.float32))
    write_exr_image(tmp_path / "y.exr", rgb[:, :, 0])
    assert np.array_equal(read_exr_image(tmp_path / "y.exr"), np.repeat(rgb[:, :, :1], 3, axis=2))
    write_raw(tmp_path / "two.exr", {"a.R": rgb[..., 0], "a.G": rgb[..., 1], "a.B": rgb[..., 2],
                                     "b.R": rgb[..., 0], "b.G": rgb[..., 1], "b.B": rgb[..., 2]})
    with pytest.raises(GsgsError, match="several colour layers \\('a', 'b'\\)"):
        read_exr_image(tmp_path / "two.exr")
    write_exr_depth(tmp_path / "d.exr", ramp(0))
    with pytest.raises(GsgsError, match="no R, G, B channels .*read_exr_depth"):
        read_exr_image(tmp_path / "d.exr")


def test_cropped_data_window_lands_in_the_display_window(tmp_path):
    crop = ramp(5, (2, 3))
    header = {"dataWindow": (np.array([1, 2], np.int32), np.array([3, 3], np.int32)),
              "displayWindow": (np.array([0, 0], np.int32), np.array([4, 4], np.int32))}
    write_raw(tmp_path / "crop.exr", {"Z": crop}, header)
    depth = read_exr_depth(tmp_path / "crop.exr")
    assert depth.shape == (5, 5) and np.array_equal(depth[2:4, 1:4], crop)
    assert np.isinf(depth[0]).all() and np.isinf(depth[:, 0]).all()
    assert read_exr_channels(tmp_path / "crop.exr")["Z"][0, 0] == 0.0


def test_bad_input_gives_clear_errors(tmp_path):
    with pytest.raises(GsgsError, match="no such EXR file"):
        read_exr_depth(tmp_path / "missing.exr")
    (tmp_path / "junk.exr").write_bytes(b"not an exr at all")
    with pytest.raises(GsgsError, match=r"junk\.exr: cannot read it as OpenEXR"):
        read_exr_image(tmp_path / "junk.exr")
    with pytest.raises(GsgsError, match="non-empty \\(H, W\\)"):
        write_exr_depth(tmp_path / "x.exr", np.zeros((2, 3, 2)))
    with pytest.raises(GsgsError, match="must be \\(H, W\\), \\(H, W, 3\\)"):
        write_exr_image(tmp_path / "x.exr", np.zeros((2, 3, 2)))
    with pytest.raises(GsgsError, match="unknown EXR compression 'lzw'"):
        write_exr_depth(tmp_path / "x.exr", np.zeros((2, 3)), compression="lzw")
    assert not (tmp_path / "x.exr").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["junk.exr"]  # no temp files left behind


@pytest.mark.slow
@pytest.mark.blender
@pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="needs the bpy module")
def test_real_blender_multilayer_render(tmp_path):
    # Render 8x6 px with Cycles into a multilayer EXR (Combined + Depth + Normal) and read it back.
    script = textwrap.dedent(f"""
        import bpy
        bpy.ops.wm.read_factory_settings(use_empty=False)  # the default cube, camera and light
        scene = bpy.context.scene
        scene.render.engine = "CYCLES"
        scene.cycles.samples = 1
        scene.cycles.device = "CPU"
        scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 8, 6, 100
        layer = scene.view_layers[0]
        layer.use_pass_z = layer.use_pass_normal = True
        scene.render.image_settings.media_type = "MULTI_LAYER_IMAGE"
        scene.render.image_settings.color_depth = "32"
        scene.render.filepath = {str(tmp_path / "render.exr")!r}
        bpy.ops.render.render(write_still=True)
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    names = set(read_exr_channels(tmp_path / "render.exr"))
    assert {"ViewLayer.Depth.Z", "ViewLayer.Combined.R", "ViewLayer.Normal.Z"} <= names
    depth = read_exr_depth(tmp_path / "render.exr")
    assert depth.shape == (6, 8)
    hit = depth < 1e9
    # the default cube (side 2) seen from the default camera about 11 units away: the front face sits near z ~ 10
    assert hit.any() and (~hit).any() and np.all((depth[hit] > 5) & (depth[hit] < 15))
    image = read_exr_image(tmp_path / "render.exr")
    assert image.shape == (6, 8, 4) and np.isfinite(image).all()
