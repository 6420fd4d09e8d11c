"""Image files for the loaders: size from the header (no decode) and lazy, picklable decoding.

Loading a scene reads only file headers; pixels are decoded by `ImageLoader` when a View asks
for them. cv2 is imported inside the functions that decode (Blender's Python has no cv2).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gsgs_engine import GsgsError
from gsgs_engine.io.scene import View

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp")


def is_image_file(path: Path) -> bool:
    return path.is_file() and path.suffix.lower() in IMAGE_EXTENSIONS and not path.name.startswith(".")


def list_images(folder: Path) -> list[Path]:
    """Image files directly in `folder`, sorted by name (the order LLFF and COLMAP splits use)."""
    return sorted((p for p in Path(folder).iterdir() if is_image_file(p)), key=lambda p: p.name)


def find_image(base: Path, stem: str) -> Path | None:
    """`base/stem` as given, else with a usual extension appended (NeRF file_path often has none)."""
    path = base / stem
    if path.is_file():
        return path
    for ext in (".png", ".jpg", ".jpeg", ".PNG", ".JPG", ".JPEG", ".exr"):
        candidate = path.with_name(path.name + ext)
        if candidate.is_file():
            return candidate
    return None


@dataclass(frozen=True)
class ImageInfo:
    width: int
    height: int
    channels: int | None  # None when the header does not say (decode to find out)


def _png_info(head: bytes) -> ImageInfo | None:
    if head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        return None
    width, height = struct.unpack(">II", head[16:24])
    color_type = head[25]
    # PNG colour types: 0 grey, 2 RGB, 3 palette, 4 grey+alpha, 6 RGBA. A tRNS chunk (rare in
    # datasets) could add alpha to 0/2/3; the decoder's channel count then wins.
    channels = {0: 1, 2: 3, 3: 3, 4: 2, 6: 4}.get(color_type)
    return ImageInfo(width, height, channels)


def _jpeg_info(fh) -> ImageInfo | None:
    fh.seek(0)
    if fh.read(2) != b"\xff\xd8":
        return None
    while True:
        byte = fh.read(1)
        while byte and byte != b"\xff":
            byte = fh.read(1)
        while byte == b"\xff":
            byte = fh.read(1)
        if not byte:
            return None
        marker = byte[0]
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:
            continue  # markers without a length field
        length_bytes = fh.read(2)
        if len(length_bytes) < 2:
            return None
        (length,) = struct.unpack(">H", length_bytes)
        # SOF0..SOF15 except DHT (C4), JPG (C8) and DAC (CC) carry the frame size.
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            data = fh.read(6)
            if len(data) < 6:
                return None
            _, height, width, channels = struct.unpack(">BHHB", data)
            return ImageInfo(width, height, channels)
        fh.seek(length - 2, 1)


def image_info(path: Path) -> ImageInfo:
    """Width, height (and channels when known) of an image, read from its header when possible."""
    path = Path(path)
    if not path.is_file():
        raise GsgsError(f"{path}: image file is missing; restore it or remove its view from the scene")
    try:
        with open(path, "rb") as fh:
            head = fh.read(32)
            info = _png_info(head) or _jpeg_info(fh)
    except OSError as exc:
        raise GsgsError(f"{path}: cannot read the image ({exc}); check the file's permissions") from exc
    if info is not None and info.width > 0 and info.height > 0:
        return info
    img = decode_image(path)  # other formats (TIFF, BMP, WebP): decode once to learn the size
    return ImageInfo(img.shape[1], img.shape[0], img.shape[2])


def decode_image(path: Path) -> np.ndarray:
    """Decode to float32 (H, W, C) in [0, 1], C = 3 (RGB) or 4 (RGBA); uint8 / uint16 are scaled."""
    try:
        import cv2
    except ImportError as exc:  # e.g. inside Blender's Python: cameras load, pixels need the engine
        raise GsgsError(f"{path}: decoding images needs OpenCV (opencv-python-headless); "
                        "run this in the gsgs engine's Python, not Blender's") from exc

    path = Path(path)
    if not path.is_file():
        raise GsgsError(f"{path}: image file is missing; restore it or remove its view from the scene")
    try:
        with open(path, "rb") as fh:
            if fh.read(2) == b"\xff\xd8":  # JPEG (whatever the extension): libjpeg would decode a truncated one
                check_jpeg_complete(b"\xff\xd8" + fh.read(), path)
    except OSError as exc:
        raise GsgsError(f"{path}: cannot read the image ({exc.strerror or exc}); check the file's permissions") from None
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise GsgsError(f"{path}: OpenCV cannot decode this image; re-save it as PNG or JPEG")
    if img.dtype == np.uint8:
        scale = 1.0 / 255.0
    elif img.dtype == np.uint16:
        scale = 1.0 / 65535.0
    elif img.dtype in (np.float32, np.float64):
        scale = 1.0
    else:
        raise GsgsError(f"{path}: unsupported pixel type {img.dtype}; re-save it as 8- or 16-bit PNG")
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2RGB)
    elif img.shape[2] == 2:  # grey + alpha
        img = np.concatenate([np.repeat(img[..., :1], 3, axis=2), img[..., 1:2]], axis=2)
    elif img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    elif img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGBA)
    else:
        raise GsgsError(f"{path}: image has {img.shape[2]} channels; expected grey, RGB or RGBA")
    return img.astype(np.float32) * np.float32(scale)


def check_jpeg_complete(data: bytes, path: Path) -> None:
    """A JPEG must end its last scan with the end-of-image marker (FF D9).

    libjpeg decodes a file cut short anyway, fills the missing rows with grey and only warns on
    stderr; such a photo would silently train a grey band into the scene. Entropy-coded data
    never holds FF D9 (a data byte FF is stuffed as FF 00), so the marker after the last
    start-of-scan (FF DA) is the image's true end; an EXIF thumbnail's own markers come before
    the main image's scans and do not count. Bytes after the marker (padding) are allowed."""
    if data[:2] != b"\xff\xd8":
        return
    last_scan = data.rfind(b"\xff\xda")
    if last_scan < 0 or data.rfind(b"\xff\xd9") < last_scan:
        raise GsgsError(f"{path}: the JPEG is truncated (no end-of-image marker after its image data; the file was cut "
                        "short by an interrupted copy or download); copy the photo again or remove it")


def check_decodable(views) -> None:
    """Decode every view's image once (and drop it): a damaged file, or a float image (EXR) holding
    NaN / Inf, stops the run before training, not after it (test views are otherwise first read by
    the final evaluation)."""
    for view in views:
        img = view.load_rgba()
        if not np.isfinite(img).all():
            raise GsgsError(f"{view.image_path}: the image holds NaN or Inf pixel values; re-export it")


@dataclass(frozen=True)
class ImageLoader:
    """A View's loader: decode `path`, undistort if needed, resize to `size` = (width, height).

    A small frozen object rather than a closure so scenes pickle (e.g. to DataLoader workers).
    """

    path: Path
    size: tuple[int, int]
    undistortion: object | None = None  # gsgs_engine.cameras.Undistortion at the file's resolution

    def __call__(self) -> np.ndarray:
        import cv2

        img = decode_image(self.path)
        if self.undistortion is not None:
            map_x, map_y = _remap_tables(self.undistortion)
            # Replicate, not black: the target camera is chosen to stay inside the photo, so only
            # sub-pixel slivers at the very border could reach outside.
            img = cv2.remap(img, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        h, w = img.shape[:2]
        if (w, h) != tuple(self.size):
            img = cv2.resize(img, tuple(self.size), interpolation=cv2.INTER_AREA)
        return img


_REMAP_CACHE: dict[int, tuple[object, tuple[np.ndarray, np.ndarray]]] = {}


def _remap_tables(undistortion) -> tuple[np.ndarray, np.ndarray]:
    """Undistortion maps, computed once per camera model (many photos share one COLMAP camera)."""
    key = id(undistortion)
    hit = _REMAP_CACHE.get(key)
    if hit is None or hit[0] is not undistortion:
        if len(_REMAP_CACHE) > 16:
            _REMAP_CACHE.clear()
        hit = (undistortion, undistortion.maps())
        _REMAP_CACHE[key] = hit
    return hit[1]


def check_same_size(entries: list[tuple[Path, ImageInfo]], what: str) -> None:
    """Every image of a split must share one size (one camera model per split downstream)."""
    if not entries:
        return
    first_path, first = entries[0]
    for path, info in entries[1:]:
        if (info.width, info.height) != (first.width, first.height):
            raise GsgsError(f"{path}: image is {info.width}x{info.height} but {first_path.name} in the same {what} "
                            f"is {first.width}x{first.height}; resize the images of a split to one size")


def make_view(camera, path: Path, resolution_scale: float, background: np.ndarray, undistortion=None):
    """A lazy View of `path` seen by `camera` (at the file's resolution), scaled by resolution_scale."""
    if resolution_scale != 1.0:
        camera = camera.scaled(resolution_scale)
    return View(camera=camera, image_path=Path(path), background=background,
                loader=ImageLoader(Path(path), (camera.width, camera.height), undistortion))
