"""Photos as phones store them (gsgs_engine.io.photos): EXIF orientation applied, HEIC read, large
photos downscaled once; and, with real pycolmap and the real bpy module, the same registered
cameras and upright Blender background photos whichever way the photos were stored."""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import zlib  # noqa: F401  -- before anything loads pycolmap (see gsgs_engine.sfm's docstring)

import numpy as np
import pytest

from conftest import shared_scene
from gsgs_engine import GsgsError
from gsgs_engine.io.photos import prepare_photos

Image = pytest.importorskip("PIL.Image")
pillow_heif = pytest.importorskip("pillow_heif")
pillow_heif.register_heif_opener()

# How each EXIF orientation stores an upright picture, written from the EXIF spec's wording
# ("the 0th row represents the visual ... side, the 0th column the visual ...") with numpy alone,
# so the test does not check Pillow's transpose against itself.
STORED = {
    1: lambda a: a,
    2: lambda a: a[:, ::-1],  # 0th row top, 0th column right: mirrored
    3: lambda a: a[::-1, ::-1],  # bottom, right: turned 180 degrees
    4: lambda a: a[::-1, :],  # bottom, left
    5: lambda a: a.transpose(1, 0, 2),  # left, top
    6: lambda a: np.rot90(a, 1),  # right, top: the phone held upright, camera app stores landscape
    7: lambda a: a[::-1, ::-1].transpose(1, 0, 2),  # right, bottom
    8: lambda a: np.rot90(a, -1),  # left, bottom
}


def _pattern(width: int = 96, height: int = 64, alpha: bool = False) -> np.ndarray:
    """An upright picture no flip or turn maps onto itself (with alpha: kept lossless, as PNG)."""
    y, x = np.mgrid[0:height, 0:width]
    img = np.stack([x * 255 // (width - 1), y * 255 // (height - 1), (x * 7 + y * 3) % 256], axis=2)
    img[:10, :20] = (255, 255, 255)  # a white block in the top-left corner
    if alpha:
        img = np.concatenate([img, np.full((height, width, 1), 255)], axis=2)
        img[-8:, -8:, 3] = 0  # a transparent bottom-right corner
    return img.astype(np.uint8)


def _exif(orientation: int, **exif_ifd) -> bytes:
    exif = Image.Exif()
    exif[0x0112] = orientation
    if exif_ifd:
        sub = exif.get_ifd(0x8769)
        for tag, value in exif_ifd.items():
            sub[int(tag.removeprefix("t"), 16)] = value
    return exif.tobytes()


def _store(upright: np.ndarray, path: Path, orientation: int, **save) -> None:
    Image.fromarray(np.ascontiguousarray(STORED[orientation](upright))).save(path, exif=_exif(orientation), **save)


def _pixels(path: Path, mode: str = "RGB") -> np.ndarray:
    with Image.open(path) as im:
        return np.asarray(im.convert(mode))


# -- one photo at a time (fast) ---------------------------------------------------------------
def test_every_exif_orientation_gives_the_upright_picture(tmp_path):
    upright = _pattern(alpha=True)
    photos = tmp_path / "photos"
    photos.mkdir()
    for o in STORED:
        _store(upright, photos / f"o{o}.png", o)  # transparent, so kept as PNG: the turned copy must be exact
    for o in (3, 6, 7):  # Pillow's TIFF decoder turns the pixels itself: not a second time
        _store(upright[..., :3], photos / f"t{o}.tif", o)  # RGB (Pillow 13 mis-turns RGBA TIFFs)
    _store(upright[..., :3], photos / "o6_jpeg.jpg", 6, quality=95)
    prepared = prepare_photos(photos, tmp_path / "upright", max_image_size=1600)
    by_source = {p.source: p for p in prepared.photos}
    for o in (3, 6, 7):
        p = by_source[f"t{o}.tif"]
        assert (p.name, p.orientation, p.size) == (f"t{o}.jpg", o, (96, 64))
        assert np.abs(_pixels(prepared.folder / p.name).astype(float) - upright[..., :3]).mean() < 6.0  # JPEG noise
    for o in STORED:
        p = by_source[f"o{o}.png"]
        assert p.orientation == o and p.size == (96, 64) and p.scale == 1.0
        assert p.stored_size == ((64, 96) if o in (5, 6, 7, 8) else (96, 64))
        np.testing.assert_array_equal(_pixels(prepared.folder / p.name, "RGBA"), upright, err_msg=f"orientation {o}")
        with Image.open(prepared.folder / p.name) as im:
            assert im.getexif().get(0x0112, 1) == 1  # no viewer turns the copy a second time
    assert by_source["o1.png"].copied  # already upright at the working size: the file itself
    jpeg = by_source["o6_jpeg.jpg"]
    assert jpeg.name == "o6_jpeg.jpg" and jpeg.size == (96, 64) and not jpeg.copied
    assert np.abs(_pixels(prepared.folder / jpeg.name).astype(float) - upright[..., :3]).mean() < 6.0
    assert prepared.summary() == ("photos: 11 turned upright by their EXIF orientation "
                                  "(orientation 2: 1, 3: 2, 4: 1, 5: 1, 6: 3, 7: 2, 8: 1)")


def test_a_transparent_tiff_is_turned_exactly_or_refused_by_name(tmp_path):
    # Pillow 13 decodes an RGBA TIFF turned by 90 degrees wrongly; never a wrong copy in silence.
    upright = _pattern(alpha=True)
    outcomes = {}
    for o in STORED:
        photos = tmp_path / f"o{o}"
        photos.mkdir()
        _store(upright, photos / "a.tif", o)
        try:
            prepared = prepare_photos(photos, tmp_path / f"upright{o}", max_image_size=1600)
        except GsgsError as exc:
            assert str(exc).startswith(f"{photos / 'a.tif'}: decoded ") and "convert the photo" in str(exc)
            outcomes[o] = "refused"
            continue
        np.testing.assert_array_equal(_pixels(prepared.folder / prepared.names[0], "RGBA"), upright)
        outcomes[o] = "exact"
    assert [o for o, outcome in outcomes.items() if outcome == "exact"][:4] == [1, 2, 3, 4], outcomes


def test_heic_is_read_and_turned_upright(tmp_path):
    upright = _pattern(128, 80)
    photos = tmp_path / "photos"
    photos.mkdir()
    Image.fromarray(upright).save(photos / "IMG_0001.HEIC", quality=95)
    # pillow-heif stores orientation 6 as the HEIF transform libheif applies on reading
    _store(upright, photos / "IMG_0002.heic", 6, quality=95)
    shutil.copy(photos / "IMG_0001.HEIC", photos / "IMG_0003.heif")
    Image.fromarray(upright).save(photos / "IMG_0003.jpg", quality=95)  # its name is taken: no clash
    prepared = prepare_photos(photos, tmp_path / "upright", max_image_size=1600)
    assert [(p.source, p.name, p.format, p.orientation) for p in prepared.photos] == [
        ("IMG_0001.HEIC", "IMG_0001.jpg", "HEIF", 1), ("IMG_0002.heic", "IMG_0002.jpg", "HEIF", 6),
        ("IMG_0003.heif", "IMG_0003.heif.jpg", "HEIF", 1), ("IMG_0003.jpg", "IMG_0003.jpg", "JPEG", 1)]
    assert prepared.photos[1].stored_size == (80, 128)
    for p in prepared.photos:
        assert p.size == (128, 80)
        assert np.abs(_pixels(prepared.folder / p.name).astype(float) - upright).mean() < 6.0, p
    assert "3 HEIF decoded" in prepared.summary()


def test_large_photo_is_downscaled_once_with_its_exif_focal_kept(tmp_path):
    small = np.random.default_rng(0).integers(0, 255, (3024 // 48, 4032 // 48, 3), dtype=np.uint8)
    stored = np.asarray(Image.fromarray(small).resize((4032, 3024), Image.Resampling.BICUBIC))  # smooth, like a photo
    photos = tmp_path / "photos"
    photos.mkdir()
    # 12 MP as a phone stores a portrait photo: landscape pixels, Orientation 6, focal-plane resolution
    exif = _exif(6, tA002=4032, tA003=3024, tA20E=2000.0, tA20F=1500.0, t920A=4.25, tA405=26)
    Image.fromarray(stored).save(photos / "portrait.jpg", exif=exif, quality=90)
    Image.fromarray(stored[:, :, ::-1]).save(photos / "other.jpg", exif=exif, quality=90)
    started = time.perf_counter()
    prepared = prepare_photos(photos, tmp_path / "upright", max_image_size=1600)
    seconds = time.perf_counter() - started
    p = {p.source: p for p in prepared.photos}["portrait.jpg"]
    assert (p.stored_size, p.size, p.orientation) == ((4032, 3024), (1200, 1600), 6)
    assert p.scale == pytest.approx(1200 / 3024)
    with Image.open(prepared.folder / p.name) as im:
        assert im.size == (1200, 1600)
        exif_ifd = im.getexif().get_ifd(0x8769)
        assert im.getexif()[0x0112] == 1
        assert (exif_ifd[0xA002], exif_ifd[0xA003]) == (1200, 1600)
        # pixels per unit on the sensor follow the pixels: scaled, and swapped with the turn
        assert float(exif_ifd[0xA20E]) == pytest.approx(1500.0 * 1200 / 3024, rel=1e-3)
        assert float(exif_ifd[0xA20F]) == pytest.approx(2000.0 * 1200 / 3024, rel=1e-3)
        assert float(exif_ifd[0x920A]) == pytest.approx(4.25) and exif_ifd[0xA405] == 26
    expected = np.asarray(Image.fromarray(np.rot90(stored, -1).copy()).resize((1200, 1600), Image.Resampling.LANCZOS))
    assert np.abs(_pixels(prepared.folder / p.name).astype(float) - expected).mean() < 3.0
    assert "2 downscaled once to the working size (e.g. other.jpg: 3024x4032 -> 1200x1600)" in prepared.summary()
    print(f"\ntwo 12 MP JPEGs turned and downscaled to 1600 px in {seconds:.2f} s")


def test_pycolmap_reads_the_phone_focal_length_from_the_upright_copies(tmp_path):
    # The focal length a phone writes is SfM's focal prior (kept fixed for small sets): it must
    # survive turning, HEIC decoding and downscaling. pycolmap runs in its own process (sfm.py).
    import subprocess
    import sys

    upright = np.asarray(Image.fromarray(_pattern(128, 96)).resize((2048, 1536)))
    photos = tmp_path / "photos"
    photos.mkdir()
    phone = {"t920A": 4.25, "tA405": 26}
    Image.fromarray(upright).save(photos / "a_upright.jpg", exif=_exif(1, **phone), quality=95)
    _store(upright, photos / "b_turned.jpg", 6, quality=95)
    Image.fromarray(np.ascontiguousarray(STORED[8](upright))).save(photos / "c_phone.heic", exif=_exif(8, **phone))
    Image.fromarray(np.ascontiguousarray(STORED[6](upright))).save(photos / "d_phone.jpg", exif=_exif(6, **phone))
    prepared = prepare_photos(photos, tmp_path / "upright", max_image_size=1600)
    assert prepared.names == ["a_upright.jpg", "b_turned.jpg", "c_phone.jpg", "d_phone.jpg"]
    code = ("import sys, pycolmap\n"
            "for path in sys.argv[1:]:\n"
            "    bitmap = pycolmap.Bitmap.read(path, False)\n"
            "    print(bitmap.width, bitmap.height, bitmap.exif_focal_length())\n")
    done = subprocess.run([sys.executable, "-c", code, *(str(prepared.folder / n) for n in prepared.names)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    rows = [line.split() for line in done.stdout.splitlines()]
    assert [r[:2] for r in rows] == [["1600", "1200"]] * 4
    focal = {name: None if r[2] == "None" else float(r[2]) for name, r in zip(prepared.names, rows)}
    assert focal["b_turned.jpg"] is None  # no EXIF focal length in that photo: none is invented
    assert focal["a_upright.jpg"] > 0
    assert focal["c_phone.jpg"] == pytest.approx(focal["a_upright.jpg"]) == focal["d_phone.jpg"]


def test_unreadable_and_unsupported_files_are_named_with_the_fix(tmp_path):
    photos = tmp_path / "photos"
    photos.mkdir()
    Image.fromarray(_pattern()).save(photos / "good.jpg")
    (photos / "IMG_0001.CR2").write_bytes(b"II*\x00raw")
    (photos / "notes.txt").write_text("not a photo")
    prepared = prepare_photos(photos, tmp_path / "upright", max_image_size=1600)
    assert prepared.names == ["good.jpg"] and prepared.skipped == ["notes.txt"]
    assert prepared.unsupported == ["IMG_0001.CR2: camera raw is not read; export it as JPEG, TIFF or HEIC"]
    (photos / "broken.heic").write_bytes(b"\x00\x00\x00\x18ftypheic" + b"\x00" * 40)
    with pytest.raises(GsgsError) as err:
        prepare_photos(photos, tmp_path / "upright", max_image_size=1600)
    assert str(err.value).startswith(f"{photos / 'broken.heic'}: cannot be read as an image (")
    assert "move it out of the folder" in str(err.value) and "\n" not in str(err.value)
    (photos / "broken.heic").unlink()
    data = (photos / "good.jpg").read_bytes()
    (photos / "cut.jpg").write_bytes(data[: len(data) // 2])
    with pytest.raises(GsgsError, match=r"cut.jpg: cannot be read as an image \(the JPEG is truncated"):
        prepare_photos(photos, tmp_path / "upright", max_image_size=1600)


# -- the same cameras, whichever way the photos were stored (real pycolmap) ---------------------
# name: (file extension, EXIF orientation per photo, save options). The lossless copies hold the
# pixels the upright JPEGs decode to, turned as the orientation says: turned back, SfM must see
# exactly the upright photos. "jpeg6" is a phone's portrait JPEG (re-encoded, so its pixels carry
# new JPEG noise) and "requality" the upright photos re-encoded at another quality: how far that
# noise alone moves a 3-photo solve, the yardstick for "jpeg6".
STORAGE = {
    "png3": (".png", (3, 3, 3), {}),
    "tiff6": (".tif", (6, 6, 6), {}),
    "png8": (".png", (8, 8, 8), {}),
    "heic": (".HEIC", (1, 6, 8), {"quality": -1, "chroma": 444, "matrix_coefficients": 0}),  # lossless HEIC
    "jpeg6": (".jpg", (6, 6, 6), {"quality": 95}),
    "requality": (".jpg", (1, 1, 1), {"quality": 90}),
}
LOSSLESS_STORAGE = ("png3", "tiff6", "png8", "heic")


@pytest.fixture(scope="module")
def solves(tmp_path_factory):
    """An SfM job on the santorini photos as given (upright JPEGs, "upright") and one per way of
    storing them in STORAGE: {name: (job, SfmResult, seconds)}."""
    from gsgs_engine.job import Job
    from gsgs_engine.sfm import run_sfm_job

    src = sorted(shared_scene("photos_santorini").glob("*.jpg"))
    root = tmp_path_factory.mktemp("stored")
    out = {}
    for variant in ("upright", *STORAGE):
        photos = root / variant
        photos.mkdir()
        for i, f in enumerate(src):
            if variant == "upright":
                shutil.copy(f, photos / f.name)
                continue
            ext, orientations, options = STORAGE[variant]
            Image.fromarray(np.ascontiguousarray(STORED[orientations[i]](_pixels(f)))).save(
                photos / f"{f.stem}{ext}", exif=_exif(orientations[i]), **options)
        job = Job.create(root / f"job_{variant}", "sfm", data={"photos": str(photos)})
        started = time.perf_counter()
        result = run_sfm_job(job)
        out[variant] = (job, result, time.perf_counter() - started)
    return out


def _attempts(report: dict) -> str:
    """The strategies an SfM report tried (registered photos, points, reprojection error): which stage differs
    when a solve moves."""
    return "; ".join(f"{a['strategy']} {a['registered']} photos {a['num_points']} points "
                     f"{a['mean_reprojection_error'] or float('nan'):.5f} px" for a in report["attempts"])


@pytest.mark.slow
def test_rotated_and_heic_photos_give_the_cameras_of_the_upright_ones(solves):
    from gsgs_engine.bench.sfm_poses import pose_errors

    _, reference, seconds = solves["upright"]
    assert reference.num_registered == 3
    ref = {c.name: c for c in reference.cameras}
    first = reference.cameras[0]
    lines = [f"upright: {first.width}x{first.height} fx {first.fx:.1f} px, {seconds:.1f} s, "
             f"{_attempts(json.loads(reference.report_path.read_text()))}"]
    measured = {}
    for variant, (_, orientations, _) in STORAGE.items():
        job, result, seconds = solves[variant]
        assert result.num_registered == 3, (variant, result.summary())
        cams = sorted(result.cameras, key=lambda c: c.name)
        assert [c.name for c in cams] == sorted(ref)  # frame_00.HEIC's copy is frame_00.jpg
        report = json.loads(result.report_path.read_text())
        assert [p["orientation"] for p in report["photos"]] == list(orientations)
        assert result.photos_note in report["notes"] and "3 downscaled once to the working size" in result.photos_note
        done = json.loads(job.progress_path.read_text().splitlines()[-1])
        assert done["stage"] == "done" and result.photos_note in done["message"]  # what the add-on shows
        err = measured[variant] = pose_errors(cams, [ref[c.name] for c in cams])
        lines.append(f"{variant}: centres {err['max_centre_pct']:.3f}% of the rig, directions "
                     f"{err['max_rotation_deg']:.3f} deg, {cams[0].width}x{cams[0].height} fx {cams[0].fx:.1f} px, "
                     f"{seconds:.1f} s, {_attempts(report)}")
        for c in cams:  # landscape cameras for landscape photos
            assert c.width > c.height and c.width == ref[c.name].width, (variant, c.name)
    print("\n" + "\n".join(lines))
    for variant in LOSSLESS_STORAGE:
        err = measured[variant]
        assert err["max_centre_pct"] < 1.0 and err["max_rotation_deg"] < 1.0, (variant, err)
        cams = {c.name: c for c in solves[variant][1].cameras}
        for name, c in ref.items():
            mine = cams[name]
            assert (mine.width, mine.height, mine.fx) == (c.width, c.height, pytest.approx(c.fx, rel=1e-3)), variant
    # A re-encoded portrait JPEG: no further off than re-encoding alone moves the solve, and far
    # from a camera turned by 90 degrees.
    noise = measured["requality"]
    assert measured["jpeg6"]["max_rotation_deg"] < max(2 * noise["max_rotation_deg"], 1.0), (measured["jpeg6"], noise)
    assert measured["jpeg6"]["max_centre_pct"] < max(2 * noise["max_centre_pct"], 1.0), (measured["jpeg6"], noise)


@pytest.mark.slow
@pytest.mark.blender
def test_blender_camera_backgrounds_show_the_rotated_photos_upright(solves):
    bpy = pytest.importorskip("bpy")
    import gsgs_blender
    from gsgs_blender.ops_photos import load_sfm_result

    _, reference, _ = solves["upright"]
    upright_images = {c.name: path for c, path in zip(reference.cameras, reference.image_paths)}
    bpy.ops.wm.read_factory_settings(use_empty=True)
    gsgs_blender.register()
    try:
        for variant in ("tiff6", "png3", "heic", "jpeg6"):
            job, result, _ = solves[variant]
            objects, _ = load_sfm_result(bpy.context.scene, job.root)
            scene = bpy.context.scene
            assert scene.render.resolution_x > scene.render.resolution_y  # a landscape frame
            cams = {c.name: c for c in result.cameras}
            assert sorted(o.name for o in objects) == sorted(cams)
            for obj in objects:
                image = obj.data.background_images[0].image
                w, h = image.size
                cam = cams[obj.name]
                assert (w, h) == (cam.width, cam.height) and w > h, (variant, obj.name, (w, h))
                # Blender's pixels, top row first, against the upright JPEGs' own solve (its undistorted photo)
                shown = np.asarray(image.pixels[:], dtype=np.float32).reshape(h, w, 4)[::-1, :, :3]
                with Image.open(upright_images[obj.name]) as im:
                    upright = np.asarray(im.convert("RGB").resize((w, h)), np.float32) / 255.0
                same = np.corrcoef(shown.ravel(), upright.ravel())[0, 1]
                turned = np.corrcoef(shown.ravel(), upright[::-1, ::-1].ravel())[0, 1]
                print(f"{variant} {obj.name}: {w}x{h}, correlation with the upright photo {same:.3f}, "
                      f"turned 180 degrees {turned:.3f}")
                assert same > 0.85 and turned < same - 0.3, (variant, obj.name, same, turned)
    finally:
        gsgs_blender.unregister()
        bpy.ops.wm.read_factory_settings(use_empty=True)
