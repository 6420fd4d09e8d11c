"""Build the installable Blender extension zip (Blender 4.2+: Edit > Preferences > Get Extensions >
Install from Disk).

    python scripts/build_extension.py [--out dist]

Zip layout (what Blender expects of an add-on extension):

    blender_manifest.toml          the repository's manifest, unchanged
    __init__.py, *.py              gsgs_blender/ (the add-on package's modules at the zip root)
    wheels/gsgs_engine_core-<version>-py3-none-any.whl
    engine/gsgs-<version>-py3-none-any.whl

The add-on imports the engine's numpy-only layer (gsgs_engine/__init__, cameras, job and the
io package). Blender installs the wheels a manifest lists into its extension site-packages, so
that layer ships as a small pure-Python wheel built here with the standard library (no pip, no
network, no torch metadata); nothing that needs torch, pycolmap or OpenCV at import time goes in.

engine/ holds the whole engine as the wheel `pip wheel . --no-deps` makes of pyproject.toml (the
`gsgs` distribution: gsgs_engine with its C++ kernel sources, the `gsgs` command; not the add-on).
The manifest does not list it: Blender's Python never installs it. The add-on's Install Engine
pip-installs it, with torch and the rest, into a separate environment (gsgs_blender/engine_install.py).
It is also left in the output folder, so `pip install dist/gsgs-*.whl` works on its own.
Zip entries have fixed timestamps (and SOURCE_DATE_EPOCH fixes the engine wheel's), so the same
sources give the same bytes.
"""

from __future__ import annotations

import argparse
import base64
import hashlib
import importlib.util
import io
import os
import re
import shutil
import subprocess
import sys
import tempfile
import tomllib
import zipfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
ENGINE_FILES = ["gsgs_engine/__init__.py", "gsgs_engine/cameras.py", "gsgs_engine/job.py", "gsgs_engine/presets.py"]
ENGINE_PACKAGES = ["gsgs_engine/io"]  # every module here is standard library + numpy at import time
WHEEL_DIST = "gsgs_engine_core"
FIXED_TIME = (2024, 1, 1, 0, 0, 0)


class BuildError(Exception):
    pass


def engine_version() -> str:
    text = (REPO / "gsgs_engine" / "__init__.py").read_text()
    m = re.search(r'^__version__\s*=\s*"([^"]+)"', text, re.M)
    if not m:
        raise BuildError("gsgs_engine/__init__.py: no __version__ = \"...\" line")
    return m.group(1)


def engine_sources() -> list[str]:
    files = list(ENGINE_FILES)
    for pkg in ENGINE_PACKAGES:
        files += sorted(p.relative_to(REPO).as_posix() for p in (REPO / pkg).glob("*.py"))
    missing = [f for f in files if not (REPO / f).is_file()]
    if missing:
        raise BuildError(f"engine files missing: {', '.join(missing)}")
    return files


def _entry(name: str) -> zipfile.ZipInfo:
    info = zipfile.ZipInfo(name, date_time=FIXED_TIME)
    info.compress_type = zipfile.ZIP_DEFLATED
    info.external_attr = 0o644 << 16
    return info


def _record_hash(data: bytes) -> str:
    return "sha256=" + base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()


def build_wheel(version: str) -> tuple[str, bytes]:
    """A py3-none-any wheel of the engine's numpy-only layer -> (file name, bytes)."""
    dist_info = f"{WHEEL_DIST}-{version}.dist-info"
    files: dict[str, bytes] = {f: (REPO / f).read_bytes() for f in engine_sources()}
    files[f"{dist_info}/METADATA"] = (
        "Metadata-Version: 2.1\n"
        f"Name: {WHEEL_DIST.replace('_', '-')}\n"
        f"Version: {version}\n"
        "Summary: gsgs engine layer for Blender: cameras, job folders, scene and PLY I/O (numpy only)\n"
        "License: GPL-3.0-or-later\n"
        "Requires-Python: >=3.11\n"
        "Requires-Dist: numpy\n").encode()
    files[f"{dist_info}/WHEEL"] = (
        "Wheel-Version: 1.0\nGenerator: gsgs scripts/build_extension.py\nRoot-Is-Purelib: true\n"
        "Tag: py3-none-any\n").encode()
    files[f"{dist_info}/top_level.txt"] = b"gsgs_engine\n"
    record = "".join(f"{name},{_record_hash(data)},{len(data)}\n" for name, data in files.items())
    record += f"{dist_info}/RECORD,,\n"
    files[f"{dist_info}/RECORD"] = record.encode()
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name, data in files.items():
            zf.writestr(_entry(name), data)
    return f"{WHEEL_DIST}-{version}-py3-none-any.whl", buf.getvalue()


def build_engine_wheel(version: str, out_dir: Path) -> Path:
    """`pip wheel . --no-deps` of the repository (setuptools from this Python) -> out_dir/gsgs-VERSION-*.whl."""
    env = dict(os.environ, SOURCE_DATE_EPOCH="1704067200")  # 2024-01-01, as FIXED_TIME
    # setuptools packs whatever build/lib holds: a module deleted from the sources must not come back from there
    shutil.rmtree(REPO / "build" / "lib", ignore_errors=True)
    with tempfile.TemporaryDirectory(prefix="gsgs_wheel_") as tmp:
        # setuptools of this Python when it has one (no network); else pip fetches it into an isolated build
        isolation = [] if importlib.util.find_spec("setuptools") is None else ["--no-build-isolation"]
        proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", *isolation,
                               "--wheel-dir", tmp, str(REPO)], capture_output=True, text=True, env=env,
                              cwd=tmp)
        built = sorted(Path(tmp).glob(f"gsgs-{version}-*.whl"))
        if proc.returncode != 0 or not built:
            tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
            raise BuildError(f"pip wheel of the engine failed: {' | '.join(tail)}")
        out_dir.mkdir(parents=True, exist_ok=True)
        target = out_dir / built[0].name
        target.write_bytes(built[0].read_bytes())
    with zipfile.ZipFile(target) as zf:
        names = zf.namelist()
    missing = [f"gsgs_engine/render/csrc/{p.name}" for p in (REPO / "gsgs_engine/render/csrc").iterdir()
               if p.suffix in (".cpp", ".h") and f"gsgs_engine/render/csrc/{p.name}" not in names]
    if missing or any(n.startswith("gsgs_blender/") for n in names):
        raise BuildError(f"{target.name}: kernel sources missing {missing} or the add-on inside; check "
                         "pyproject.toml's packages and package-data")
    return target


def read_manifest() -> dict:
    path = REPO / "blender_manifest.toml"
    try:
        return tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise BuildError(f"{path}: cannot read the manifest ({exc})") from exc


def build(out_dir: Path) -> Path:
    manifest = read_manifest()
    version = engine_version()
    if manifest.get("version") != version:
        raise BuildError(f"blender_manifest.toml version {manifest.get('version')!r} != gsgs_engine "
                         f"{version!r}; make them equal")
    wheel_name, wheel_bytes = build_wheel(version)
    engine_wheel = build_engine_wheel(version, out_dir)
    wheel_path = f"wheels/{wheel_name}"
    if manifest.get("wheels") != [f"./{wheel_path}"]:
        raise BuildError(f"blender_manifest.toml wheels = {manifest.get('wheels')}; set it to [\"./{wheel_path}\"]")
    addon_files = sorted(p for p in (REPO / "gsgs_blender").glob("*.py"))
    if not any(p.name == "__init__.py" for p in addon_files):
        raise BuildError("gsgs_blender/__init__.py is missing")
    out_dir.mkdir(parents=True, exist_ok=True)
    zip_path = out_dir / f"{manifest['id']}-{version}.zip"
    with zipfile.ZipFile(zip_path, "w") as zf:
        zf.writestr(_entry("blender_manifest.toml"), (REPO / "blender_manifest.toml").read_bytes())
        for path in addon_files:
            zf.writestr(_entry(path.name), path.read_bytes())
        zf.writestr(_entry(wheel_path), wheel_bytes)
        zf.writestr(_entry(f"engine/{engine_wheel.name}"), engine_wheel.read_bytes())
    return zip_path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default=str(REPO / "dist"), help="output folder (default: dist/)")
    args = parser.parse_args(argv)
    try:
        path = build(Path(args.out))
    except BuildError as exc:
        print(f"build_extension: error: {exc}", file=sys.stderr)
        return 2
    with zipfile.ZipFile(path) as zf:
        names = zf.namelist()
    print(f"{path} ({path.stat().st_size / 1024:.0f} KiB, {len(names)} files)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
