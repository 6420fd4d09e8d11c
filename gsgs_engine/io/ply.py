"""Gaussian-splat and point-cloud PLY files, numpy only (Blender's Python imports results).

Splats use the de-facto 3DGS layout, so files open in other splat viewers and splats from
other tools import: `x y z nx ny nz f_dc_0..2 f_rest_* opacity scale_0..2 rot_0..3`,
opacity as a logit, scale as a log, rotation as a quaternion w, x, y, z, and `f_rest`
channel-major (all red coefficients, then green, then blue).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gsgs_engine import GsgsError

SH_C0 = 0.28209479177387814  # Y_0^0: colour = SH_C0 * f_dc + 0.5

# Defaults for PLYs that are plain point clouds: the values 3DGS initialises splats with
# (opacity 0.1, identity rotation, grey), so such a file reads as a training start.
DEFAULT_OPACITY = 0.1

_REST_COUNTS = {0: 0, 9: 1, 24: 2, 45: 3}  # number of f_rest_* -> SH degree
_PLY_TO_NUMPY = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_NUMPY_TO_PLY = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort",
                 "i4": "int", "u4": "uint", "f4": "float", "f8": "double"}
_FORMATS = {"binary_little_endian": "<", "binary_big_endian": ">", "ascii": ""}
_MAX_HEADER_BYTES = 1 << 20

_POSITION = ("x", "y", "z")
_NORMAL = ("nx", "ny", "nz")
_DC = ("f_dc_0", "f_dc_1", "f_dc_2")
_SCALE = ("scale_0", "scale_1", "scale_2")
_ROT = ("rot_0", "rot_1", "rot_2", "rot_3")
_COLOR = ("red", "green", "blue")
# A file with any of these is a splat file and must have all of them.
_GAUSSIAN_REQUIRED = _DC + ("opacity",) + _SCALE + _ROT


@dataclass(eq=False)
class GaussianPly:
    """Splat parameters as stored (logits, logs), one row per Gaussian, float32.

    `extra` keeps every per-point property this layout does not name (4D motion fields,
    colours another tool wrote, ...) in file order, with its stored dtype; writing puts them
    back after the canonical properties. `defaulted` lists the fields a reader filled in
    because the file lacked them (see `read_gaussian_ply`).
    """

    positions: np.ndarray  # (N, 3)
    opacity_logits: np.ndarray  # (N,)
    log_scales: np.ndarray  # (N, 3)
    quats_wxyz: np.ndarray  # (N, 4), any norm
    sh_dc: np.ndarray  # (N, 3)
    sh_rest: np.ndarray  # (N, K-1, 3), K-1 in {0, 3, 8, 15}
    normals: np.ndarray | None = None  # (N, 3); None -> zeros, as 3DGS writes
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    defaulted: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        f32 = lambda a: np.asarray(a, dtype=np.float32)  # noqa: E731
        self.positions = f32(self.positions)
        n = self.positions.shape[0] if self.positions.ndim == 2 else -1
        if self.normals is None:
            self.normals = np.zeros((max(n, 0), 3), np.float32)
        self.opacity_logits = f32(self.opacity_logits)
        if self.opacity_logits.ndim == 2 and self.opacity_logits.shape[1] == 1:  # 3DGS keeps (N, 1)
            self.opacity_logits = self.opacity_logits[:, 0]
        self.log_scales, self.quats_wxyz = f32(self.log_scales), f32(self.quats_wxyz)
        self.sh_dc, self.sh_rest, self.normals = f32(self.sh_dc), f32(self.sh_rest), f32(self.normals)
        expected = {
            "positions": (n, 3), "opacity_logits": (n,), "log_scales": (n, 3), "quats_wxyz": (n, 4),
            "sh_dc": (n, 3), "normals": (n, 3),
        }
        for name, shape in expected.items():
            got = getattr(self, name).shape
            if n < 0 or got != shape:
                raise GsgsError(f"GaussianPly: {name} has shape {got}, expected {shape if n >= 0 else '(N, 3)'}")
        rest = self.sh_rest
        if rest.ndim != 3 or rest.shape[0] != n or rest.shape[2] != 3 or rest.shape[1] * 3 not in _REST_COUNTS:
            raise GsgsError(f"GaussianPly: sh_rest has shape {rest.shape}, expected ({n}, 0|3|8|15, 3)")
        extra = {}
        for key, value in self.extra.items():
            value = np.asarray(value)
            if value.shape != (n,):
                raise GsgsError(f"GaussianPly: extra property {key!r} has shape {value.shape}, expected ({n},)")
            extra[key] = value
        self.extra = extra

    def __len__(self) -> int:
        return self.positions.shape[0]

    @property
    def sh_degree(self) -> int:
        return _REST_COUNTS[self.sh_rest.shape[1] * 3]

    # Activated values, for viewers (the Blender import) that show splats as stored.
    def rgb(self) -> np.ndarray:
        """Base colour (degree-0 SH) in [0, 1], (N, 3)."""
        return np.clip(self.sh_dc * SH_C0 + 0.5, 0.0, 1.0)

    def opacity(self) -> np.ndarray:
        return 0.5 * (1.0 + np.tanh(0.5 * self.opacity_logits))  # sigmoid without exp overflow

    def scales(self) -> np.ndarray:
        return np.exp(self.log_scales)


# ----------------------------------------------------------------------------- header


@dataclass
class _Element:
    name: str
    count: int
    properties: list[tuple[str, str]]  # (name, numpy type code without byte order)
    list_property: str | None = None  # a face list: fine only in an empty element


def _parse_header(path: Path) -> tuple[str, list[_Element], int]:
    """-> (format, elements, byte offset of the data)."""
    with open(path, "rb") as f:
        magic = f.readline(16)
        if magic.rstrip(b"\r\n") != b"ply":
            raise GsgsError(f"{path}: not a PLY file (it does not start with 'ply'); pass a .ply point cloud or splat file")
        fmt = None
        elements: list[_Element] = []
        while True:
            line = f.readline(65536)
            if not line.endswith(b"\n"):
                raise GsgsError(f"{path}: the PLY header has no 'end_header' line; the file is truncated or not a PLY")
            if f.tell() > _MAX_HEADER_BYTES:
                raise GsgsError(f"{path}: the PLY header is longer than 1 MiB; the file is not a valid PLY")
            words = line.decode("ascii", errors="replace").split()
            if not words or words[0] in ("comment", "obj_info"):
                continue
            if words[0] == "end_header":
                break
            if words[0] == "format":
                if len(words) < 2 or words[1] not in _FORMATS:
                    raise GsgsError(f"{path}: unknown PLY format {' '.join(words[1:])!r}; expected ascii, binary_little_endian or binary_big_endian")
                fmt = words[1]
            elif words[0] == "element":
                if len(words) != 3 or not words[2].isdigit():
                    raise GsgsError(f"{path}: malformed PLY header line {line.strip()!r}; expected 'element NAME COUNT'")
                elements.append(_Element(words[1], int(words[2]), []))
            elif words[0] == "property":
                if not elements:
                    raise GsgsError(f"{path}: PLY header has a property before any element; the header is malformed")
                element = elements[-1]
                if len(words) >= 2 and words[1] == "list":
                    element.list_property = words[-1]
                    continue
                if len(words) != 3 or words[1] not in _PLY_TO_NUMPY:
                    raise GsgsError(f"{path}: malformed or unknown PLY property {line.strip()!r}; expected 'property TYPE NAME' with a PLY scalar type")
                if any(name == words[2] for name, _ in element.properties):
                    raise GsgsError(f"{path}: element {element.name!r} declares property {words[2]!r} twice; the header is malformed")
                element.properties.append((words[2], _PLY_TO_NUMPY[words[1]]))
            else:
                raise GsgsError(f"{path}: unexpected PLY header line {line.strip()!r}")
        if fmt is None:
            raise GsgsError(f"{path}: the PLY header has no 'format' line; the header is malformed")
        for element in elements:
            # Point-cloud writers often declare an empty face element; a non-empty one is a mesh.
            if element.list_property is not None and element.count > 0:
                raise GsgsError(
                    f"{path}: element {element.name!r} has list property {element.list_property!r} (a mesh's faces); "
                    "gsgs reads point clouds and splats only: export the vertices alone (as a point cloud) and try again")
        return fmt, elements, f.tell()


def _row_dtype(element: _Element, byte_order: str) -> np.dtype:
    return np.dtype([(name, byte_order + code) for name, code in element.properties])


def _read_element(path: Path, wanted: str) -> np.ndarray:
    """The structured array (native byte order) of element `wanted`."""
    fmt, elements, offset = _parse_header(path)
    names = [e.name for e in elements]
    if wanted not in names:
        raise GsgsError(f"{path}: the PLY has no {wanted!r} element (elements: {', '.join(names) or 'none'})")
    size = path.stat().st_size
    if fmt == "ascii":
        return _read_ascii(path, elements, offset, wanted)
    order = _FORMATS[fmt]
    expected = offset + sum(e.count * _row_dtype(e, order).itemsize for e in elements)
    if size != expected:
        what = "truncated" if size < expected else "longer than its header describes"
        raise GsgsError(
            f"{path}: the PLY is {what} ({size} bytes, header says {expected}); re-export or re-download the file")
    for element in elements:
        dtype = _row_dtype(element, order)
        if element.name == wanted:
            data = np.fromfile(path, dtype=dtype, count=element.count, offset=offset)
            return data if order == "<" and np.little_endian else data.astype(dtype.newbyteorder("="))
        offset += element.count * dtype.itemsize
    raise AssertionError("unreachable")


def _read_ascii(path: Path, elements: list[_Element], offset: int, wanted: str) -> np.ndarray:
    with open(path, "rb") as f:
        f.seek(offset)
        tokens = f.read().split()
    needed = sum(e.count * len(e.properties) for e in elements)
    if len(tokens) != needed:
        what = "truncated" if len(tokens) < needed else "longer than its header describes"
        raise GsgsError(f"{path}: the ASCII PLY is {what} ({len(tokens)} values, header says {needed}); re-export the file")
    start = 0
    for element in elements:
        width = len(element.properties)
        if element.name == wanted:
            try:
                values = np.array(tokens[start:start + element.count * width], dtype=np.float64)
            except ValueError as exc:
                raise GsgsError(f"{path}: the ASCII PLY has a value that is not a number ({exc}); fix or re-export the file") from None
            values = values.reshape(element.count, width)
            out = np.empty(element.count, dtype=_row_dtype(element, "="))
            for j, (name, _) in enumerate(element.properties):
                out[name] = values[:, j]
            return out
        start += element.count * width
    raise AssertionError("unreachable")


# ----------------------------------------------------------------------------- reading


def read_ply_vertices(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Every property of a PLY's `vertex` element, in file order, with its stored dtype.

    For generic point clouds (COLMAP's points3D.ply, scans): e.g. x, y, z, red, green, blue.
    """
    data = _read_element(_existing(path), "vertex")
    return {name: np.ascontiguousarray(data[name]) for name in data.dtype.names or ()}


def nonfinite_rows(g: GaussianPly) -> tuple[int, list[str]]:
    """(number of splats with a NaN / Inf value, the properties holding them)."""
    if len(g) == 0:
        return 0, []
    bad = np.zeros(len(g), bool)
    fields = []
    arrays = {"x/y/z": g.positions, "opacity": g.opacity_logits, "scale_*": g.log_scales, "rot_*": g.quats_wxyz,
              "f_dc_*": g.sh_dc, "f_rest_*": g.sh_rest.reshape(len(g), -1)}
    arrays.update({k: v for k, v in g.extra.items() if np.issubdtype(v.dtype, np.floating)})
    for name, values in arrays.items():
        rows = ~np.isfinite(values).reshape(len(g), -1).all(axis=1)
        if rows.any():
            bad |= rows
            fields.append(name)
    return int(bad.sum()), fields


def check_finite(g: GaussianPly, path) -> GaussianPly:
    """`g`, or a GsgsError naming `path` when a value is NaN or Inf (such a splat renders as nothing or
    poisons the whole image)."""
    count, fields = nonfinite_rows(g)
    if count:
        raise GsgsError(f"{path}: {count} of {len(g)} splats hold NaN or Inf values (in {', '.join(fields)}); the "
                        "file is damaged or comes from a run that diverged: re-export or retrain it")
    return g


def read_gaussian_ply(path: str | os.PathLike, require_finite: bool = True) -> GaussianPly:
    """Read a 3DGS-layout splat PLY, in any property order, binary (either endianness) or ASCII.

    A file with any of opacity / scale_* / rot_* must have all of them and a colour. Colour is
    f_dc_*, else red/green/blue as sh_dc = (c - 0.5) / SH_C0 (integers scaled by their
    type's maximum, floats taken as [0, 1], or as [0, 255] when any exceeds 1), else grey.
    Files without opacity / scale / rotation are point clouds and get 3DGS's initial values:
    opacity 0.1, identity rotation, isotropic scale sqrt(bounding-box surface area / N) (the
    spacing of N points spread over the box's surface), SH degree 0. `defaulted` lists what
    was filled in. Missing normals are zeros; float64 values are rounded to float32;
    properties outside the layout are kept in `extra`. With `require_finite` (the default) a
    NaN or Inf anywhere is a GsgsError naming the file (`check_finite`).
    """
    path = _existing(path)
    data = _read_element(path, "vertex")
    names = list(data.dtype.names or ())
    present = set(names)
    n = data.shape[0]
    used: set[str] = set()
    defaulted: list[str] = []

    def columns(cols: tuple[str, ...]) -> np.ndarray:
        used.update(cols)
        return _float32_columns(data, cols)

    def require(cols: tuple[str, ...], why: str) -> None:
        missing = [c for c in cols if c not in present]
        if missing:
            raise GsgsError(f"{path}: the PLY vertex element lacks {', '.join(missing)} ({why}); "
                            f"it has: {', '.join(names) or 'nothing'}")

    hint = "; it has packed_* properties: a compressed splat PLY, decompress it first" if any(
        c.startswith("packed_") for c in names) else ""
    require(_POSITION, "every splat or point needs a position" + hint)
    positions = columns(_POSITION)

    if any(c in present for c in _NORMAL):
        require(_NORMAL, "normals must have all three components")
        normals = columns(_NORMAL)
    else:
        normals = np.zeros((n, 3), np.float32)

    rest_names = [c for c in names if c.startswith("f_rest_")]
    rest_ids = sorted(int(c[7:]) for c in rest_names if c[7:].isdigit())
    if len(rest_names) not in _REST_COUNTS or rest_ids != list(range(len(rest_names))):
        raise GsgsError(
            f"{path}: the PLY has {len(rest_names)} f_rest_* properties; a 3DGS file has f_rest_0.. f_rest_M-1 with "
            "M = 0, 9, 24 or 45 (SH degree 0-3); re-export it from its tool")
    k1 = len(rest_names) // 3
    rest = columns(tuple(f"f_rest_{i}" for i in range(len(rest_names))))
    sh_rest = np.ascontiguousarray(rest.reshape(n, 3, k1).transpose(0, 2, 1))  # channel-major on disk

    is_gaussian = any(c in present for c in ("opacity",) + _SCALE + _ROT)
    has_colors = all(c in present for c in _COLOR)
    if is_gaussian:
        why = "a splat file needs f_dc_0..2 (or red, green, blue), opacity, scale_0..2 and rot_0..3"
        require(_GAUSSIAN_REQUIRED if not has_colors else _GAUSSIAN_REQUIRED[3:], why)
    if all(c in present for c in _DC):
        sh_dc = columns(_DC)
    elif has_colors:
        sh_dc = _colors_to_sh_dc(np.stack([data[c] for c in _COLOR], axis=1))
        used.update(_COLOR)
        defaulted.append("sh_dc")
    else:
        sh_dc = np.zeros((n, 3), np.float32)  # grey 0.5
        defaulted.append("sh_dc")
    if is_gaussian:
        opacity_logits = columns(("opacity",))[:, 0].copy()
        log_scales = columns(_SCALE)
        quats = columns(_ROT)
    else:
        opacity_logits = np.full(n, np.log(DEFAULT_OPACITY / (1.0 - DEFAULT_OPACITY)), np.float32)
        log_scales = np.full((n, 3), np.log(_spacing_estimate(positions)), np.float32)
        quats = np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1))
        defaulted += ["opacity_logits", "log_scales", "quats_wxyz"]

    extra = {c: np.ascontiguousarray(data[c]) for c in names if c not in used}
    g = GaussianPly(positions, opacity_logits, log_scales, quats, sh_dc, sh_rest, normals, extra, tuple(defaulted))
    return check_finite(g, path) if require_finite else g


def _float32_columns(data: np.ndarray, cols: tuple[str, ...]) -> np.ndarray:
    """(N, len(cols)) float32 from a structured array, in one pass when the columns sit side
    by side with one dtype (the usual case: ~3x faster than stacking fields for 1M splats)."""
    n = data.shape[0]
    if not cols:
        return np.zeros((n, 0), np.float32)
    fields = data.dtype.fields
    first_dtype, first_offset = fields[cols[0]][:2]
    adjacent = all(fields[c][0] == first_dtype and fields[c][1] == first_offset + i * first_dtype.itemsize
                   for i, c in enumerate(cols))
    if adjacent and data.flags.c_contiguous and n > 0:
        raw = data.view(np.uint8).reshape(n, data.dtype.itemsize)
        block = raw[:, first_offset:first_offset + len(cols) * first_dtype.itemsize].view(first_dtype)
        return block.astype(np.float32)
    return np.stack([data[c] for c in cols], axis=1).astype(np.float32)


def _colors_to_sh_dc(colors: np.ndarray) -> np.ndarray:
    if np.issubdtype(colors.dtype, np.integer):
        unit = colors.astype(np.float64) / np.iinfo(colors.dtype).max
    else:
        unit = colors.astype(np.float64)
        if unit.size and np.nanmax(unit) > 1.0:
            unit = unit / 255.0
    return ((unit - 0.5) / SH_C0).astype(np.float32)


def _spacing_estimate(positions: np.ndarray) -> float:
    """Typical distance between neighbours of N points lying on their bounding box's surface."""
    n = positions.shape[0]
    finite = positions[np.all(np.isfinite(positions), axis=1)]
    if n == 0 or finite.shape[0] == 0:
        return 0.01
    ex, ey, ez = (finite.max(axis=0) - finite.min(axis=0)).astype(np.float64)
    area = 2.0 * (ex * ey + ey * ez + ez * ex)
    if area > 0:
        return float(np.sqrt(area / n))
    longest = max(ex, ey, ez)
    return float(longest / n) if longest > 0 else 0.01


def _existing(path: str | os.PathLike) -> Path:
    path = Path(path)
    if not path.is_file():
        raise GsgsError(f"{path}: no such PLY file; check the path")
    return path


# ----------------------------------------------------------------------------- writing


def write_ply_vertices(path: str | os.PathLike, columns: dict[str, np.ndarray]) -> None:
    """Write one `vertex` element, binary little endian, properties in dict order.

    Each column is (N,); bool is stored as uchar, and int64 / uint64 as int / uint when the
    values fit (PLY has no 64-bit integers). The file appears atomically (temp + rename),
    so a crash never leaves a truncated PLY where a viewer would open it.
    """
    _write_vertex_blocks(Path(path), [((name,), np.asarray(values)[:, None] if np.ndim(values) == 1 else np.asarray(values))
                                      for name, values in columns.items()])


def _write_vertex_blocks(path: Path, blocks: list[tuple[tuple[str, ...], np.ndarray]]) -> None:
    """Write (names, (N, len(names)) array) blocks side by side; one byte copy per block."""
    prepared: list[tuple[tuple[str, ...], np.ndarray]] = []
    seen: set[str] = set()
    n = None
    for names, values in blocks:
        for name in names:
            if not name or any(ch.isspace() for ch in name):
                raise GsgsError(f"{path}: PLY property name {name!r} must be non-empty without spaces")
            if name in seen:
                raise GsgsError(f"{path}: PLY property {name!r} appears twice; rename one")
            seen.add(name)
        values = _storable(path, names[0], values)
        if values.ndim != 2 or values.shape[1] != len(names) or (n is not None and values.shape[0] != n):
            shape = values.shape if len(names) > 1 else values.shape[:1]
            raise GsgsError(f"{path}: PLY property {names[0]!r} has shape {shape}; every property needs shape ({n if n is not None else 'N'},)")
        n = values.shape[0]
        prepared.append((names, values.astype(values.dtype.newbyteorder("<"), copy=False)))
    n = n or 0
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {n}"]
    header += [f"property {_NUMPY_TO_PLY[values.dtype.str[1:]]} {name}" for names, values in prepared for name in names]
    header.append("end_header")
    if len({values.dtype for _, values in prepared}) <= 1:  # e.g. all float32: one gathering copy
        rows = np.concatenate([values for _, values in prepared], axis=1) if prepared else np.empty((n, 0), np.uint8)
    else:
        row_bytes = sum(values.shape[1] * values.dtype.itemsize for _, values in prepared)
        rows = np.empty((n, row_bytes), np.uint8)
        offset = 0
        for _, values in prepared:
            width = values.shape[1] * values.dtype.itemsize
            rows[:, offset:offset + width] = np.ascontiguousarray(values).view(np.uint8).reshape(n, width)
            offset += width
    _atomic_write(path, ("\n".join(header) + "\n").encode("ascii"), rows)


def _storable(path: Path, name: str, values: np.ndarray) -> np.ndarray:
    if values.dtype == np.bool_:
        return values.astype(np.uint8)
    if values.dtype.kind in "iu" and values.dtype.itemsize == 8:
        target = np.int32 if values.dtype.kind == "i" else np.uint32
        info = np.iinfo(target)
        if values.size and (values.min() < info.min or values.max() > info.max):
            raise GsgsError(f"{path}: PLY property {name!r} holds 64-bit integers beyond 32 bits; PLY cannot store them, store them as float64")
        return values.astype(target)
    if values.dtype.str[1:] not in _NUMPY_TO_PLY:
        raise GsgsError(f"{path}: PLY property {name!r} has dtype {values.dtype}, which PLY cannot store; use float32/float64 or an integer type")
    return values


def _atomic_write(path: Path, header: bytes, rows: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as f:
            f.write(header)
            rows.tofile(f)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def write_gaussian_ply(path: str | os.PathLike, splats: GaussianPly) -> None:
    """Write the canonical 3DGS layout (binary little endian, float32), then `extra` in its order."""
    path = Path(path)
    n = len(splats)
    rest = splats.sh_rest.transpose(0, 2, 1).reshape(n, 3 * splats.sh_rest.shape[1])  # channel-major, as 3DGS
    blocks = [(_POSITION, splats.positions), (_NORMAL, splats.normals), (_DC, splats.sh_dc),
              (tuple(f"f_rest_{i}" for i in range(rest.shape[1])), rest),
              (("opacity",), splats.opacity_logits[:, None]), (_SCALE, splats.log_scales), (_ROT, splats.quats_wxyz)]
    blocks = [(names, values) for names, values in blocks if names]
    canonical = {name for names, _ in blocks for name in names}
    for name, values in splats.extra.items():
        if name in canonical:
            raise GsgsError(f"{path}: extra property {name!r} clashes with a standard 3DGS property; rename it")
        blocks.append(((name,), values[:, None]))
    _write_vertex_blocks(path, blocks)
