"""A folder of photos without poses: listed here, posed by `gsgs sfm`, never loaded directly.

`prepare_photos` is the one place where photos as cameras and phones store them become the
pictures every later stage reads: EXIF orientation applied (pixels turned upright), HEIC / HEIF
and the other usual formats decoded, large photos downscaled once to the working size. SfM runs
on these upright copies, so its cameras, the undistorted images that training and validation
read, and the Blender cameras' background photos all show what the photographer saw.

Pillow (and pillow-heif for HEIC) is imported inside the functions that decode, as cv2 is in
io/images.py: this module stays importable in Blender's Python, which has neither.
"""

from __future__ import annotations

import math
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from gsgs_engine import GsgsError

# Decoded by Pillow (+ pillow-heif); JPEG, PNG, TIFF and BMP are also what pycolmap reads itself,
# so an upright photo of those formats at the working size is copied byte for byte.
PHOTO_EXTENSIONS = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp", ".webp", ".heic", ".heif")
COLMAP_READABLE = {"JPEG", "PNG", "TIFF", "BMP"}
# A photo that must change is re-encoded as JPEG (quality 95): the same pixels give the same copy
# whatever format they came in. Only a picture with transparency or more than 8 bits becomes a PNG.
KEEP_AS_PNG_MODES = {"RGBA", "LA", "PA"}
WIDE_MODES = {"I", "I;16", "I;16B", "I;16L", "F"}  # one channel, more than 8 bits: scaled to 8
# Photo formats that are recognised but not read, with what to do instead.
UNSUPPORTED = {ext: "camera raw is not read; export it as JPEG, TIFF or HEIC"
               for ext in (".dng", ".cr2", ".cr3", ".nef", ".arw", ".raf", ".orf", ".rw2", ".pef", ".srw")}
UNSUPPORTED.update({".gif": "GIF (256 colours) is not read; export the photo as JPEG or PNG",
                    ".avif": "AVIF is not read; export it as JPEG or HEIC",
                    ".jxl": "JPEG XL is not read; export it as JPEG or HEIC"})
MIN_PHOTO_SIDE = 32  # SIFT finds nothing below this; pycolmap crashed (exit -11) on 1x1 photos
JPEG_QUALITY = 95

ORIENTATION = 0x0112  # EXIF tags (IFD0, and the Exif IFD 0x8769)
EXIF_IFD = 0x8769
PIXEL_X_DIMENSION, PIXEL_Y_DIMENSION = 0xA002, 0xA003
FOCAL_PLANE_X_RESOLUTION, FOCAL_PLANE_Y_RESOLUTION = 0xA20E, 0xA20F
KEPT_IFD0_TAGS = (0x010F, 0x0110, 0x0132)  # Make, Model, DateTime
TURNS_90 = {5, 6, 7, 8}  # orientations whose upright picture swaps width and height
DECODER_TURNS = {"HEIF", "TIFF"}  # formats whose decoder applies the orientation itself


def is_photo_file(path: Path) -> bool:
    return path.is_file() and path.suffix.lower() in PHOTO_EXTENSIONS and not path.name.startswith(".")


def photo_folder(root: Path) -> Path | None:
    """The folder holding the photos (`root` or root/images), or None when there are none."""
    for folder in (root, root / "images"):
        if folder.is_dir() and any(is_photo_file(p) for p in folder.iterdir()):
            return folder
    return None


def list_photos(root) -> list[Path]:
    """The photos of a photo folder, sorted by name (what `gsgs sfm` reconstructs)."""
    folder = photo_folder(Path(root))
    if folder is None:
        raise GsgsError(f"{root}: no photos ({', '.join(PHOTO_EXTENSIONS)}) here or in images/; "
                        "add the photos to reconstruct")
    return sorted((p for p in folder.iterdir() if is_photo_file(p)), key=lambda p: p.name)


def needs_sfm_error(path) -> GsgsError:
    """Photos have no cameras yet: the error that says how to get them (SfM writes a COLMAP folder)."""
    count = len(list_photos(path))
    return GsgsError(f"{path}: {count} photos without camera poses; run `gsgs sfm {path} --out DIR` first, "
                     "then load DIR (a COLMAP folder)")


def load_photos(path, **_ignored):
    raise needs_sfm_error(path)


# ---------------------------------------------------------------------------------------
# Photos as stored -> upright working copies
# ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PreparedPhoto:
    """What was done to one photo: `source` (its file name in the photo folder) became `name`
    (its upright working copy), `size` = stored size turned by `orientation`, times `scale`."""

    source: str
    name: str
    format: str  # as Pillow names it: JPEG, PNG, TIFF, BMP, WEBP, HEIF
    orientation: int  # the EXIF orientation applied (1: stored upright)
    stored_size: tuple[int, int]  # (width, height) of the pixels as stored
    size: tuple[int, int]  # (width, height) of the upright working copy
    scale: float  # working size / upright stored size (1.0: not downscaled)
    copied: bool  # the file itself, byte for byte (already upright, at most the working size, read by COLMAP)

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class PreparedPhotos:
    folder: Path  # the upright working copies
    photos: list[PreparedPhoto]
    skipped: list[str]  # files that are not photos
    unsupported: list[str]  # "name: why; what to do" for photo files that are not read

    @property
    def names(self) -> list[str]:
        return [p.name for p in self.photos]

    @property
    def sizes(self) -> dict[str, tuple[int, int]]:
        return {p.name: p.size for p in self.photos}

    def summary(self) -> str:
        """One line for the report: what was turned, decoded or downscaled ('' when nothing was)."""
        parts = []
        turned = [p for p in self.photos if p.orientation != 1]
        if turned:
            counts = {o: sum(p.orientation == o for p in turned) for o in sorted({p.orientation for p in turned})}
            parts.append(f"{len(turned)} turned upright by their EXIF orientation "
                         f"(orientation {', '.join(f'{o}: {n}' for o, n in counts.items())})")
        for fmt in sorted({p.format for p in self.photos} - COLMAP_READABLE):
            count = sum(p.format == fmt for p in self.photos)
            parts.append(f"{count} {fmt} decoded")
        scaled = [p for p in self.photos if p.scale != 1.0]
        if scaled:
            first = scaled[0]
            upright = (first.stored_size[::-1] if first.orientation in TURNS_90 else first.stored_size)
            parts.append(f"{len(scaled)} downscaled once to the working size "
                         f"(e.g. {first.source}: {upright[0]}x{upright[1]} -> {first.size[0]}x{first.size[1]})")
        return f"photos: {'; '.join(parts)}" if parts else ""


def scan_photo_folder(photo_dir) -> tuple[list[Path], list[str], list[str]]:
    """(photo files, names of files that are not photos, "name: why; what to do" for photo files in
    a format that is not read) directly in `photo_dir`, sorted by name; nothing is decoded."""
    photo_dir = Path(photo_dir)
    if not photo_dir.is_dir():
        raise GsgsError(f"{photo_dir}: not a folder; pass the folder that holds the photos")
    sources, skipped, unsupported = [], [], []
    for path in sorted(photo_dir.iterdir()):
        if path.name.startswith(".") or path.is_dir():
            continue
        ext = path.suffix.lower()
        if ext in PHOTO_EXTENSIONS:
            sources.append(path)
        elif ext in UNSUPPORTED:
            unsupported.append(f"{path.name}: {UNSUPPORTED[ext]}")
        else:
            skipped.append(path.name)
    return sources, skipped, unsupported


def prepare_photos(photo_dir, out_dir, max_image_size: int) -> PreparedPhotos:
    """Upright copies of the photos in `photo_dir`, no larger than `max_image_size` on their longest
    side, written to `out_dir` (emptied first). A file that cannot be read is an error naming it
    and the fix; a photo in a format that is not read is listed in `unsupported`."""
    out_dir = Path(out_dir)
    sources, skipped, unsupported = scan_photo_folder(photo_dir)
    if out_dir.exists():
        shutil.rmtree(out_dir)
    out_dir.mkdir(parents=True)
    taken = {p.name.lower() for p in sources}  # a re-encoded copy never takes another photo's name
    photos = []
    for path in sources:
        photos.append(_prepare_one(path, out_dir, int(max_image_size), taken))
    return PreparedPhotos(folder=out_dir, photos=photos, skipped=skipped, unsupported=unsupported)


def _open(path: Path):
    """The photo opened by Pillow (lazily), or a GsgsError naming the file and the fix."""
    try:
        from PIL import Image
    except ImportError as exc:
        raise GsgsError(f"{path}: reading photos needs Pillow; install it into the engine's Python "
                        "(pip install Pillow pillow-heif)") from exc
    if path.suffix.lower() in (".heic", ".heif"):
        try:
            import pillow_heif
        except ImportError as exc:
            raise GsgsError(f"{path}: HEIC / HEIF photos need pillow-heif; install it into the engine's Python "
                            "(pip install pillow-heif) or export the photo as JPEG") from exc
        pillow_heif.register_heif_opener()
    try:
        with open(path, "rb") as fh:
            head = fh.read(2)
            if head == b"\xff\xd8":  # Pillow, like libjpeg, would fill a cut-off JPEG with grey rows
                from gsgs_engine.io.images import check_jpeg_complete

                check_jpeg_complete(head + fh.read(), path)
        return Image.open(path)
    except GsgsError as exc:
        raise GsgsError(f"{path}: cannot be read as an image ({str(exc).removeprefix(f'{path}: ')}); "
                        "copy the photo again or move it out of the folder") from None
    except (OSError, ValueError, SyntaxError) as exc:
        what = path.suffix.lstrip(".").upper() or "an image"
        raise GsgsError(f"{path}: cannot be read as an image ({exc}; corrupt or not really {what}); "
                        "re-export it as JPEG or move it out of the folder") from None


def _prepare_one(path: Path, out_dir: Path, max_size: int, taken: set[str]) -> PreparedPhoto:
    from PIL import Image, ImageOps

    image = _open(path)
    try:
        fmt = image.format or path.suffix.lstrip(".").upper()
        # libheif turns HEIF pixels itself (and keeps the tag it read aside); Pillow's TIFF decoder
        # turns TIFF pixels on load. Both report the upright size when opened.
        decoder_turns = fmt in DECODER_TURNS
        orientation = int((image.info.get("original_orientation") if fmt == "HEIF"
                           else image.getexif().get(ORIENTATION)) or 1)
        if orientation not in range(1, 9):
            orientation = 1  # an invalid tag: cameras and viewers show such a photo as stored
        turns = orientation in TURNS_90
        stored = image.size[::-1] if decoder_turns and turns else image.size
        upright = stored[::-1] if turns else stored
        if min(upright) < MIN_PHOTO_SIDE:
            raise GsgsError(f"{path}: the photo is {upright[0]}x{upright[1]} pixels; structure from motion needs "
                            f"at least {MIN_PHOTO_SIDE} pixels on each side to find features: use the full-size photos")
        scale = min(1.0, max_size / max(upright))
        size = (max(1, round(upright[0] * scale)), max(1, round(upright[1] * scale))) if scale < 1 else upright
        if orientation == 1 and scale == 1.0 and fmt in COLMAP_READABLE:
            _decode(image, path)
            shutil.copyfile(path, out_dir / path.name)
            return PreparedPhoto(path.name, path.name, fmt, 1, stored, size, 1.0, True)
        if scale < 1 and fmt == "JPEG":  # decode at 1/2, 1/4 or 1/8 scale when that is still large enough
            image.draft(None, size[::-1] if turns else size)
        _decode(image, path)
        exif = image.getexif()
        turned = ImageOps.exif_transpose(image) if orientation != 1 and not decoder_turns else image
        if turned.mode in WIDE_MODES:
            wide = np.asarray(turned, dtype=np.float64)
            peak = 255.0 if turned.mode in ("I", "F") and wide.max() <= 255 else 65535.0
            turned = Image.fromarray(np.clip(wide * (255.0 / peak) + 0.5, 0, 255).astype(np.uint8), "L")
        lossless = turned.mode in KEEP_AS_PNG_MODES or (turned.mode == "P" and "transparency" in turned.info)
        if turned.mode not in (("L", "RGB", "RGBA") if lossless else ("L", "RGB")):
            turned = turned.convert("RGBA" if lossless else "RGB")
        if upright[0] != upright[1] and (turned.width > turned.height) != (upright[0] > upright[1]):
            raise GsgsError(f"{path}: decoded {turned.width}x{turned.height} for an upright {upright[0]}x{upright[1]} "
                            f"photo (EXIF orientation {orientation}); this Pillow turns {fmt} differently, "
                            "so convert the photo to JPEG and report it")
        if turned.size != size:
            turned = turned.resize(size, Image.Resampling.LANCZOS, reducing_gap=3.0)
        name = _copy_name(path, ".png" if lossless else ".jpg", taken)
        options = {"exif": _working_exif(exif, orientation, size, scale).tobytes()}
        if image.info.get("icc_profile"):
            options["icc_profile"] = image.info["icc_profile"]
        if not lossless:
            options["quality"] = JPEG_QUALITY
        try:
            turned.save(out_dir / name, **options)
        except OSError as exc:
            raise GsgsError(f"{out_dir / name}: could not write the upright copy ({exc}); "
                            "check the folder is writable and has free space") from None
        return PreparedPhoto(path.name, name, fmt, orientation, stored, size, round(size[0] / upright[0], 6), False)
    finally:
        image.close()


def _decode(image, path: Path) -> None:
    try:
        image.load()
    except (OSError, ValueError, SyntaxError) as exc:
        raise GsgsError(f"{path}: cannot be decoded ({exc}); re-export it as JPEG or move it out of the "
                        "folder") from None


def _copy_name(path: Path, ext: str, taken: set[str]) -> str:
    """The working copy's name: the photo's stem with the new extension, or the full name plus it
    when that would take another photo's name (IMG_1.heic next to IMG_1.jpg)."""
    name = path.stem + ext
    if name.lower() != path.name.lower() and name.lower() in taken:
        name = path.name + ext
    taken.add(name.lower())
    return name


def _working_exif(source, orientation: int, size: tuple[int, int], scale: float):
    """The photo's EXIF for its upright working copy: the camera's make, model and date, orientation
    1, and the Exif IFD (focal length, 35 mm equivalent: what COLMAP reads for a focal prior) with the
    copy's pixel dimensions and the focal-plane resolution (pixels per unit on the sensor, which
    COLMAP may use to turn millimetres into pixels) scaled with the pixels and swapped when the
    picture turned. A TIFF's layout tags and any GPS position are left out."""
    from PIL import Image

    exif = Image.Exif()
    for tag in KEPT_IFD0_TAGS:
        if tag in source:
            exif[tag] = source[tag]
    exif[ORIENTATION] = 1
    sub = dict(source.get_ifd(EXIF_IFD))
    if sub:
        exif.get_ifd(EXIF_IFD).update(sub)
        sub = exif.get_ifd(EXIF_IFD)
        if PIXEL_X_DIMENSION in sub or PIXEL_Y_DIMENSION in sub:
            sub[PIXEL_X_DIMENSION], sub[PIXEL_Y_DIMENSION] = size
        x_res, y_res = sub.get(FOCAL_PLANE_X_RESOLUTION), sub.get(FOCAL_PLANE_Y_RESOLUTION)
        if orientation in TURNS_90:
            x_res, y_res = y_res, x_res
        for tag, value in ((FOCAL_PLANE_X_RESOLUTION, x_res), (FOCAL_PLANE_Y_RESOLUTION, y_res)):
            if value is not None and math.isfinite(float(value)) and float(value) > 0:
                sub[tag] = float(value) * scale
    return exif
