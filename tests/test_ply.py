"""Gaussian PLY read/write: 3DGS byte layout, round trips, foreign files and clear errors."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from gsgs_engine import GsgsError
from gsgs_engine.io.ply import (
    DEFAULT_OPACITY,
    SH_C0,
    GaussianPly,
    read_gaussian_ply,
    read_ply_vertices,
    write_gaussian_ply,
    write_ply_vertices,
)

FIELDS = ("positions", "opacity_logits", "log_scales", "quats_wxyz", "sh_dc", "sh_rest", "normals")


def random_splats(n: int, degree: int, seed: int = 0, extra: bool = False) -> GaussianPly:
    rng = np.random.default_rng(seed)
    k1 = (degree + 1) ** 2 - 1
    f = lambda *shape: rng.standard_normal(shape, dtype=np.float32)  # noqa: E731
    ex = {}
    if extra:
        ex = {"t_center": f(n), "motion_0": rng.normal(size=n), "label": rng.integers(0, 255, n).astype(np.uint8)}
    return GaussianPly(f(n, 3), f(n), f(n, 3), f(n, 4), f(n, 3), f(n, k1, 3), f(n, 3), ex)


def assert_same(a: GaussianPly, b: GaussianPly) -> None:
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype == np.float32 and x.shape == y.shape, name
        assert np.array_equal(x.view(np.uint32), y.view(np.uint32)), name  # bit-exact, NaN payloads too
    assert list(a.extra) == list(b.extra)
    for key in a.extra:
        assert a.extra[key].dtype == b.extra[key].dtype and np.array_equal(a.extra[key], b.extra[key]), key


def raw_ply(path, props: list[tuple[str, str, np.ndarray]], fmt="binary_little_endian", elements_after=()) -> None:
    """Write a PLY by hand (independent of the module under test): props = (ply type, name, values)."""
    n = len(props[0][2]) if props else 0
    order = ">" if fmt == "binary_big_endian" else "<"
    codes = {"float": "f4", "double": "f8", "uchar": "u1", "int": "i4", "short": "i2"}
    lines = ["ply", f"format {fmt} 1.0", "comment written by a test"] + ([f"element vertex {n}"] if props else [])
    lines += [f"property {t} {name}" for t, name, _ in props]
    for name, count, plines in elements_after:
        lines += [f"element {name} {count}"] + plines
    lines.append("end_header")
    header = ("\n".join(lines) + "\n").encode()
    if fmt == "ascii":
        body = "\n".join(" ".join(repr(float(v[i])) if t in ("float", "double") else str(int(v[i]))
                                  for t, _, v in props) for i in range(n)) + "\n"
        path.write_bytes(header + body.encode())
        return
    rows = np.empty(n, dtype=[(name, order + codes[t]) for t, name, _ in props])
    for _, name, v in props:
        rows[name] = v
    path.write_bytes(header + rows.tobytes())


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_round_trip_is_bit_exact(tmp_path, degree):
    splats = random_splats(257, degree, seed=degree, extra=True)
    splats.positions[0, 0] = np.nan
    splats.log_scales[1, 2] = -np.inf
    path = tmp_path / "a.ply"
    write_gaussian_ply(path, splats)
    back = read_gaussian_ply(path, require_finite=False)  # NaN / Inf survive a raw round trip bit for bit
    assert back.sh_degree == degree and len(back) == 257 and back.defaulted == ()
    assert back.extra["motion_0"].dtype == np.float64  # stored dtype kept
    assert_same(splats, back)
    write_gaussian_ply(tmp_path / "b.ply", back)
    assert (tmp_path / "b.ply").read_bytes() == path.read_bytes()


def test_bytes_match_the_3dgs_writer(tmp_path):
    # What 3DGS's GaussianModel.save_ply writes (plyfile, dtype 'f4' per attribute), rebuilt by hand.
    n, k1 = 5, 8
    splats = random_splats(n, 2, seed=3)
    rest_names = [f"f_rest_{i}" for i in range(3 * k1)]
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", *rest_names, "opacity",
             "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    f_rest = np.transpose(splats.sh_rest, (0, 2, 1)).reshape(n, -1)  # features_rest.transpose(1, 2).flatten(1)
    body = np.concatenate([splats.positions, splats.normals, splats.sh_dc, f_rest, splats.opacity_logits[:, None],
                           splats.log_scales, splats.quats_wxyz], axis=1).astype("<f4")
    header = "ply\nformat binary_little_endian 1.0\nelement vertex 5\n" + "".join(
        f"property float {name}\n" for name in names) + "end_header\n"
    write_gaussian_ply(tmp_path / "a.ply", splats)
    assert (tmp_path / "a.ply").read_bytes() == header.encode() + body.tobytes()
    # channel-major: f_rest_{c * k1 + k} is coefficient k of channel c
    back = read_ply_vertices(tmp_path / "a.ply")
    assert back["f_rest_9"][2] == splats.sh_rest[2, 1, 1]


def test_any_property_order_big_endian_and_float64(tmp_path):
    splats = random_splats(40, 1, seed=5)
    cols = {"x": splats.positions[:, 0], "y": splats.positions[:, 1], "z": splats.positions[:, 2],
            "opacity": splats.opacity_logits}
    cols.update({f"f_dc_{i}": splats.sh_dc[:, i] for i in range(3)})
    cols.update({f"scale_{i}": splats.log_scales[:, i] for i in range(3)})
    cols.update({f"rot_{i}": splats.quats_wxyz[:, i] for i in range(4)})
    rest = np.transpose(splats.sh_rest, (0, 2, 1)).reshape(40, -1)
    cols.update({f"f_rest_{i}": rest[:, i] for i in range(9)})
    names = list(cols)[::-1]  # reversed order, no normals
    props = [("double" if name in ("x", "y", "z") else "float", name, cols[name]) for name in names]
    raw_ply(tmp_path / "be.ply", props, fmt="binary_big_endian")
    back = read_gaussian_ply(tmp_path / "be.ply")
    for name in FIELDS[:-1]:
        assert np.array_equal(getattr(back, name), getattr(splats, name)), name
    assert np.array_equal(back.normals, np.zeros((40, 3), np.float32)) and back.extra == {}


def test_ascii_ply(tmp_path):
    xyz = np.array([[0.5, -1.25, 3.0], [1e-3, 2.0, -7.5]])
    rgb = np.array([[255, 0, 128], [10, 20, 30]])
    raw_ply(tmp_path / "a.ply", [("float", "x", xyz[:, 0]), ("float", "y", xyz[:, 1]), ("float", "z", xyz[:, 2]),
                                 ("uchar", "red", rgb[:, 0]), ("uchar", "green", rgb[:, 1]), ("uchar", "blue", rgb[:, 2])],
            fmt="ascii")
    v = read_ply_vertices(tmp_path / "a.ply")
    assert v["red"].dtype == np.uint8 and list(v["blue"]) == [128, 30]
    assert np.array_equal(np.stack([v["x"], v["y"], v["z"]], 1), xyz.astype(np.float32))
    g = read_gaussian_ply(tmp_path / "a.ply")
    assert np.allclose(g.rgb(), rgb / 255.0, atol=1e-6)


def test_point_cloud_gets_3dgs_initial_values(tmp_path):
    xyz = np.array([[0, 0, 0], [2, 0, 0], [0, 1, 0], [0, 0, 4]], np.float64)
    rgb = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [128, 128, 128]], np.uint8)
    raw_ply(tmp_path / "pc.ply", [("double", "x", xyz[:, 0]), ("double", "y", xyz[:, 1]), ("double", "z", xyz[:, 2]),
                                  ("uchar", "red", rgb[:, 0]), ("uchar", "green", rgb[:, 1]), ("uchar", "blue", rgb[:, 2]),
                                  ("int", "point_id", np.arange(4))])
    g = read_gaussian_ply(tmp_path / "pc.ply")
    assert g.positions.dtype == np.float32 and np.array_equal(g.positions, xyz.astype(np.float32))
    assert np.allclose(g.sh_dc, (rgb / 255.0 - 0.5) / SH_C0, atol=1e-6)
    assert np.allclose(g.opacity(), DEFAULT_OPACITY, atol=1e-6)
    assert np.array_equal(g.quats_wxyz, np.tile([1.0, 0, 0, 0], (4, 1)).astype(np.float32))
    spacing = np.sqrt(2 * (2 * 1 + 1 * 4 + 4 * 2) / 4)  # bounding box 2 x 1 x 4, 4 points
    assert np.allclose(g.scales(), spacing, rtol=1e-6)
    assert g.sh_degree == 0 and set(g.defaulted) == {"sh_dc", "opacity_logits", "log_scales", "quats_wxyz"}
    assert list(g.extra) == ["point_id"] and g.extra["point_id"].dtype == np.int32
    write_gaussian_ply(tmp_path / "out.ply", g)  # a point cloud imports as splats and writes back as 3DGS
    assert np.array_equal(read_gaussian_ply(tmp_path / "out.ply").extra["point_id"], np.arange(4))


def test_xyz_only_is_grey_and_float_colours(tmp_path):
    raw_ply(tmp_path / "a.ply", [("float", "x", np.arange(3.0)), ("float", "y", np.zeros(3)), ("float", "z", np.zeros(3))])
    g = read_gaussian_ply(tmp_path / "a.ply")
    assert np.allclose(g.rgb(), 0.5) and g.normals.shape == (3, 3)
    raw_ply(tmp_path / "b.ply", [("float", "x", np.zeros(2)), ("float", "y", np.zeros(2)), ("float", "z", np.zeros(2)),
                                 ("float", "red", [0.25, 200.0]), ("float", "green", [0.0, 0.0]), ("float", "blue", [1.0, 255.0])])
    assert np.allclose(read_gaussian_ply(tmp_path / "b.ply").rgb()[1], [200 / 255, 0, 1])  # >1 means 0..255


def test_splats_with_uchar_colours_instead_of_f_dc(tmp_path):
    n = 3
    props = [("float", c, np.arange(n) + 1.0) for c in ("x", "y", "z", "opacity", "scale_0", "scale_1", "scale_2")]
    props += [("float", f"rot_{i}", np.ones(n)) for i in range(4)]
    props += [("uchar", c, np.array([0, 51, 255])) for c in ("red", "green", "blue")]
    raw_ply(tmp_path / "a.ply", props)
    g = read_gaussian_ply(tmp_path / "a.ply")
    assert g.defaulted == ("sh_dc",) and g.extra == {}
    assert np.allclose(g.rgb()[:, 0], [0.0, 0.2, 1.0], atol=1e-6) and np.array_equal(g.opacity_logits, [1, 2, 3])


def test_truncated_and_oversized_files_are_refused(tmp_path):
    path = tmp_path / "a.ply"
    write_gaussian_ply(path, random_splats(10, 1))
    data = path.read_bytes()
    (tmp_path / "short.ply").write_bytes(data[:-5])
    with pytest.raises(GsgsError, match=r"short\.ply: the PLY is truncated"):
        read_gaussian_ply(tmp_path / "short.ply")
    (tmp_path / "long.ply").write_bytes(data + b"\0\0\0\0")
    with pytest.raises(GsgsError, match="longer than its header"):
        read_gaussian_ply(tmp_path / "long.ply")
    (tmp_path / "nohead.ply").write_bytes(data[:100])
    with pytest.raises(GsgsError, match="end_header"):
        read_gaussian_ply(tmp_path / "nohead.ply")
    raw_ply(tmp_path / "asc.ply", [("float", "x", [1.0, 2.0]), ("float", "y", [1.0, 2.0]), ("float", "z", [1.0, 2.0])], fmt="ascii")
    (tmp_path / "asc.ply").write_bytes((tmp_path / "asc.ply").read_bytes()[:-4])
    with pytest.raises(GsgsError, match="ASCII PLY is truncated"):
        read_ply_vertices(tmp_path / "asc.ply")


def test_bad_files_give_clear_errors(tmp_path):
    xyz = [("float", c, np.zeros(2)) for c in "xyz"]
    raw_ply(tmp_path / "mesh.ply", xyz, elements_after=[("face", 1, ["property list uchar int vertex_indices"])])
    with pytest.raises(GsgsError, match="list property 'vertex_indices'"):
        read_gaussian_ply(tmp_path / "mesh.ply")
    raw_ply(tmp_path / "noface.ply", xyz, elements_after=[("face", 0, ["property list uchar int vertex_indices"])])
    assert len(read_gaussian_ply(tmp_path / "noface.ply")) == 2  # an empty face element, as many tools write
    raw_ply(tmp_path / "partial.ply", xyz + [("float", "opacity", np.zeros(2)), ("float", "scale_0", np.zeros(2))])
    with pytest.raises(GsgsError, match=r"lacks f_dc_0, f_dc_1, f_dc_2, scale_1, scale_2, rot_0, rot_1, rot_2, rot_3"):
        read_gaussian_ply(tmp_path / "partial.ply")
    raw_ply(tmp_path / "noxyz.ply", [("float", "x", np.zeros(2)), ("int", "packed_position", np.zeros(2))])
    with pytest.raises(GsgsError, match="lacks y, z .*compressed splat PLY"):
        read_gaussian_ply(tmp_path / "noxyz.ply")
    raw_ply(tmp_path / "rest.ply", xyz + [("float", f"f_rest_{i}", np.zeros(2)) for i in range(6)])
    with pytest.raises(GsgsError, match="6 f_rest_"):
        read_gaussian_ply(tmp_path / "rest.ply")
    (tmp_path / "txt.ply").write_text("hello\n")
    with pytest.raises(GsgsError, match="not a PLY file"):
        read_gaussian_ply(tmp_path / "txt.ply")
    with pytest.raises(GsgsError, match="no such PLY file"):
        read_gaussian_ply(tmp_path / "missing.ply")
    raw_ply(tmp_path / "other.ply", [], elements_after=[("camera", 0, ["property float k"])])
    with pytest.raises(GsgsError, match="has no 'vertex' element"):
        read_ply_vertices(tmp_path / "other.ply")


def test_other_elements_are_skipped(tmp_path):
    # a scalar element after the vertices (e.g. a camera block) counts in the size check and is skipped
    xyz = [("float", c, np.arange(3.0) + i) for i, c in enumerate("xyz")]
    raw_ply(tmp_path / "a.ply", xyz, elements_after=[("camera", 2, ["property float k"])])
    (tmp_path / "a.ply").write_bytes((tmp_path / "a.ply").read_bytes() + np.zeros(2, "<f4").tobytes())
    assert list(read_ply_vertices(tmp_path / "a.ply")["z"]) == [2.0, 3.0, 4.0]


def test_write_validation_and_generic_columns(tmp_path):
    with pytest.raises(GsgsError, match="sh_rest has shape"):
        GaussianPly(np.zeros((2, 3)), np.zeros(2), np.zeros((2, 3)), np.zeros((2, 4)), np.zeros((2, 3)), np.zeros((2, 4, 3)))
    with pytest.raises(GsgsError, match="log_scales has shape"):
        GaussianPly(np.zeros((2, 3)), np.zeros(2), np.zeros((3, 3)), np.zeros((2, 4)), np.zeros((2, 3)), np.zeros((2, 0, 3)))
    g = random_splats(3, 0)
    g.extra["opacity"] = np.zeros(3, np.float32)
    with pytest.raises(GsgsError, match="clashes"):
        write_gaussian_ply(tmp_path / "a.ply", g)
    write_ply_vertices(tmp_path / "p.ply", {"x": np.arange(4.0), "id": np.arange(4), "ok": np.ones(4, bool)})
    v = read_ply_vertices(tmp_path / "p.ply")
    assert v["x"].dtype == np.float64 and v["id"].dtype == np.int32 and v["ok"].dtype == np.uint8
    with pytest.raises(GsgsError, match="beyond 32 bits"):
        write_ply_vertices(tmp_path / "q.ply", {"id": np.array([2**40])})
    with pytest.raises(GsgsError, match=r"'b' has shape \(2,\)"):
        write_ply_vertices(tmp_path / "q.ply", {"a": np.zeros(3), "b": np.zeros(2)})
    assert not (tmp_path / "q.ply").exists()


def test_empty_and_opacity_column_shape(tmp_path):
    g = random_splats(0, 3)
    write_gaussian_ply(tmp_path / "e.ply", g)
    back = read_gaussian_ply(tmp_path / "e.ply")
    assert len(back) == 0 and back.sh_rest.shape == (0, 15, 3)
    g = GaussianPly(np.zeros((2, 3)), np.ones((2, 1)), np.zeros((2, 3)), np.ones((2, 4)), np.zeros((2, 3)), np.zeros((2, 3, 3)))
    assert g.opacity_logits.shape == (2,) and g.sh_degree == 1  # 3DGS keeps opacity as (N, 1)


@pytest.mark.slow
def test_million_splats_sh3_speed(tmp_path):
    splats = random_splats(1_000_000, 3, extra=False)
    t0 = time.perf_counter()
    write_gaussian_ply(tmp_path / "big.ply", splats)
    t1 = time.perf_counter()
    back = read_gaussian_ply(tmp_path / "big.ply")
    t2 = time.perf_counter()
    print(f"\n1,000,000 splats SH3 ({(tmp_path / 'big.ply').stat().st_size / 2**20:.0f} MiB): "
          f"write {t1 - t0:.2f} s, read {t2 - t1:.2f} s")
    assert_same(splats, back)
    assert t1 - t0 < 30 and t2 - t1 < 30  # generous for a loaded 2-core CI box; a per-point loop takes minutes


def test_reads_colmap_point_cloud_export(tmp_path):
    # A real foreign writer: COLMAP's points3D PLY export (x y z float, red green blue uchar).
    pycolmap = pytest.importorskip("pycolmap")
    rec = pycolmap.Reconstruction()
    xyz = np.array([[0.5, 1.0, 2.0], [-1.0, 0.25, 3.0], [2.0, -2.0, 4.5]])
    rgb = np.array([[255, 0, 0], [0, 128, 0], [10, 20, 30]], np.uint8)
    for p, c in zip(xyz, rgb):
        rec.add_point3D(p, pycolmap.Track(), c)
    rec.export_PLY(str(tmp_path / "points3D.ply"))
    v = read_ply_vertices(tmp_path / "points3D.ply")
    order = np.argsort(v["z"])  # COLMAP writes its points in its own order
    assert np.allclose(np.stack([v["x"], v["y"], v["z"]], 1)[order], xyz)
    assert np.array_equal(np.stack([v["red"], v["green"], v["blue"]], 1)[order], rgb)
    g = read_gaussian_ply(tmp_path / "points3D.ply")
    assert np.allclose(g.rgb()[order], rgb / 255.0, atol=1e-6) and "sh_dc" in g.defaulted


@pytest.mark.slow
@pytest.mark.blender
@pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="needs the bpy module")
def test_blender_reads_ours_and_we_read_blenders(tmp_path):
    # Blender's own PLY importer/exporter as an independent implementation of the format.
    splats = random_splats(7, 1, seed=11, extra=True)
    write_gaussian_ply(tmp_path / "ours.ply", splats)
    script = textwrap.dedent(f"""
        import bpy, json, numpy as np
        bpy.ops.wm.read_factory_settings(use_empty=True)
        bpy.ops.wm.ply_import(filepath={str(tmp_path / "ours.ply")!r})
        mesh = bpy.context.selected_objects[0].data
        out = {{"co": [list(v.co) for v in mesh.vertices]}}
        for name in ("opacity", "f_rest_4", "rot_3", "t_center"):
            out[name] = [d.value for d in mesh.attributes[name].data]
        bpy.ops.wm.ply_export(filepath={str(tmp_path / "blender.ply")!r}, ascii_format=False, export_normals=False,
                              export_colors="NONE", export_uv=False)
        bpy.ops.wm.ply_export(filepath={str(tmp_path / "blender_ascii.ply")!r}, ascii_format=True, export_normals=False,
                              export_colors="NONE", export_uv=False)
        print("RESULT " + json.dumps(out))
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    seen = json.loads(next(line[7:] for line in done.stdout.splitlines() if line.startswith("RESULT ")))
    assert np.allclose(seen["co"], splats.positions, atol=1e-6)
    assert np.allclose(seen["opacity"], splats.opacity_logits, atol=1e-6)
    assert np.allclose(seen["f_rest_4"], splats.sh_rest[:, 1, 1], atol=1e-6)  # channel-major: 4 = G of coefficient 1
    assert np.allclose(seen["rot_3"], splats.quats_wxyz[:, 3], atol=1e-6)
    assert np.allclose(seen["t_center"], splats.extra["t_center"], atol=1e-6)
    for name in ("blender.ply", "blender_ascii.ply"):
        v = read_ply_vertices(tmp_path / name)
        assert np.allclose(np.stack([v["x"], v["y"], v["z"]], 1), splats.positions, atol=1e-6), name
