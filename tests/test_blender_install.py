"""Install Engine (issue 32): the engine wheel, the installer's choices and messages, and the whole
path an artist takes: the extension zip installed with Blender's "Install from Disk" in a fresh
HOME, Install Engine from the package index (real venv, real pip), Check Engine, and photos ->
cameras -> train -> import with the engine it installed; a bad package index and a cancel leave
the previous engine working and say why in one line."""

from __future__ import annotations

import io
import json
import os
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from conftest import REPO, shared_scene

bpy = pytest.importorskip("bpy")
from gsgs_blender import engine_installer  # noqa: E402

pytestmark = pytest.mark.blender
INSTALLER = REPO / "gsgs_blender" / "engine_installer.py"


def _build(out: Path) -> Path:
    sys.path.insert(0, str(REPO / "scripts"))
    try:
        import build_extension
    finally:
        sys.path.pop(0)
    return build_extension.build(out)


def _engine_wheel(zip_path: Path) -> tuple[str, zipfile.ZipFile]:
    with zipfile.ZipFile(zip_path) as zf:
        name = next(n for n in zf.namelist() if n.startswith("engine/") and n.endswith(".whl"))
        return name, zipfile.ZipFile(io.BytesIO(zf.read(name)))


def _requirements_for(wheel: zipfile.ZipFile, python_version: str) -> list[str]:
    """The wheel's Requires-Dist lines whose markers hold for `python_version` (no extras), markers dropped."""
    from packaging.requirements import Requirement

    meta = wheel.read(next(n for n in wheel.namelist() if n.endswith(".dist-info/METADATA"))).decode()
    reqs = [Requirement(r) for r in re.findall(r"^Requires-Dist: (.+)$", meta, re.M)]
    return [f"{r.name}{r.specifier}" for r in reqs
            if r.marker is None or r.marker.evaluate({"python_version": python_version, "extra": ""})]


def test_the_zip_carries_the_engine_wheel_with_its_kernel_sources_and_nothing_of_the_addon(tmp_path):
    import gsgs_engine

    path = _build(tmp_path / "dist")
    name, wheel = _engine_wheel(path)
    assert name == f"engine/gsgs-{gsgs_engine.__version__}-py3-none-any.whl"
    assert (tmp_path / "dist" / Path(name).name).is_file()  # also next to the zip: pip install dist/gsgs-*.whl
    names = set(wheel.namelist())
    csrc = {f"gsgs_engine/render/csrc/{p.name}" for p in (REPO / "gsgs_engine/render/csrc").iterdir()
            if p.suffix in (".cpp", ".h")}
    assert csrc and csrc <= names
    assert {"gsgs_engine/__main__.py", "gsgs_engine/commands/build_ext.py", "gsgs_engine/lpips/fetch.py"} <= names
    assert not any(n.startswith(("gsgs_blender", "tests/", "scripts/")) for n in names)
    meta = wheel.read(next(n for n in names if n.endswith(".dist-info/METADATA"))).decode()
    entry = wheel.read(next(n for n in names if n.endswith(".dist-info/entry_points.txt"))).decode()
    assert "gsgs = gsgs_engine.cli:main" in entry
    requires = re.search(r"^Requires-Python: (.+)$", meta, re.M).group(1)
    assert engine_installer.python_allowed(requires, (3, 11)) and engine_installer.python_allowed(requires, (3, 13))
    assert not engine_installer.python_allowed(requires, (3, 10))
    # the manifest asks Blender to install only the numpy-only layer, never the engine wheel
    import tomllib

    with zipfile.ZipFile(path) as zf:
        manifest = tomllib.loads(zf.read("blender_manifest.toml").decode())
    assert not any("engine/" in w for w in manifest["wheels"]) and manifest["permissions"]["network"]


def test_torch_build_choice_says_why():
    url, why = engine_installer.torch_choice("auto", "", None)
    assert url == engine_installer.TORCH_CPU_INDEX and "CPU build" in why and "no NVIDIA GPU" in why
    url, why = engine_installer.torch_choice("auto", "", "NVIDIA H100 80GB HBM3")
    assert "CUDA build" in why and "H100" in why
    assert url == (engine_installer.TORCH_CUDA_INDEX_WINDOWS if os.name == "nt" else None)
    assert engine_installer.torch_choice("index", "", None)[0] is None
    assert engine_installer.torch_choice("cpu", "http://mirror/cpu", None)[0] == "http://mirror/cpu"


def test_pip_failures_are_one_line_naming_the_cause_and_the_fix():
    offline = ("WARNING: Retrying (Retry(total=4...)) after connection broken by 'NewConnectionError(...: "
               "Failed to establish a new connection: [Errno 111] Connection refused')': /simple/pycolmap/\n"
               "ERROR: Could not find a version that satisfies the requirement pycolmap>=4.2 (from gsgs) "
               "(from versions: none)\nERROR: No matching distribution found for pycolmap>=4.2\n")
    text = engine_installer.pip_failure("engine", offline, "http://127.0.0.1:9/simple")
    assert "\n" not in text and "could not reach http://127.0.0.1:9/simple" in text and "pycolmap>=4.2" in text
    assert "Package Index" in text and "Engine Python" in text
    text = engine_installer.pip_failure("torch", "ERROR: No matching distribution found for torch==9\n", None)
    assert "pip failed: No matching distribution found for torch==9" in text and "could not reach" not in text


def test_an_unsupported_python_is_refused_before_anything_is_made(tmp_path):
    old = next((p for p in sorted(Path.home().glob(".pyenv/versions/3.10*/bin/python3.10"))), None)
    if old is None:
        pytest.skip("no Python 3.10 on this machine (pyenv)")
    out = subprocess.run([str(old), str(INSTALLER), "--env", str(tmp_path / "env"), "--source", str(REPO),
                          "--progress", str(tmp_path / "p.jsonl")], capture_output=True, text=True, timeout=60)
    assert out.returncode == 1 and not (tmp_path / "env").exists()
    final = json.loads((tmp_path / "p.jsonl").read_text().splitlines()[-1])
    assert final["state"] == "error" and "is Python 3.10, the engine needs" in final["message"]


def test_no_compiler_is_found_on_an_empty_path_and_the_cost_is_stated(tmp_path, monkeypatch):
    assert engine_installer.compiler() is not None or pytest.skip("no C++ compiler on this machine")
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.delenv("CXX", raising=False)
    assert engine_installer.compiler() is None
    assert "reference (pure torch) rasteriser" in engine_installer.NO_COMPILER_COST
    assert "10-30x slower" in engine_installer.NO_COMPILER_COST


@pytest.mark.slow
def test_check_engine_reports_a_version_mismatch(tmp_path):
    from gsgs_blender.preferences import check_engine

    fake = tmp_path / "gsgs_engine"
    fake.mkdir()
    (fake / "__init__.py").write_text('__version__ = "0.0.1"\n')
    ok, report = check_engine(sys.executable, str(tmp_path))
    assert not ok
    assert f"the engine in Engine Source {tmp_path} is 0.0.1, this add-on is" in report and "update" in report


@pytest.mark.slow
def test_the_engine_requirements_have_python_313_wheels(tmp_path):
    """Every requirement of the engine wheel, with its markers read for Python 3.13, resolves to a
    binary wheel for CPython 3.13 on Linux x86-64 from pip's configured index (no install)."""
    name, wheel = _engine_wheel(_build(tmp_path / "dist"))
    for_313 = _requirements_for(wheel, "3.13")
    assert any(r.startswith("numpy") and ">=2.1" in r for r in for_313) and any(r.startswith("torch") for r in for_313)
    for req in for_313:
        out = subprocess.run([sys.executable, "-m", "pip", "install", "--dry-run", "--no-deps", "--ignore-installed",
                              "--only-binary=:all:", "--python-version", "3.13", "--implementation", "cp",
                              "--platform", "manylinux_2_28_x86_64", "--platform", "manylinux_2_17_x86_64",
                              "--target", str(tmp_path / "t"), req], capture_output=True, text=True, timeout=600)
        assert out.returncode == 0 and "Would install" in out.stdout, req + "\n" + out.stdout[-1500:] + out.stderr[-1500:]


@pytest.mark.slow
def test_the_engine_installs_on_python_313_apart_from_torch(tmp_path):
    """A real Python 3.13 venv: the engine wheel and every dependency but torch (whose 3.13 wheel on
    this index is the CUDA build, its CUDA libraries absent here) install, and the numpy-only layer,
    pycolmap, OpenCV and OpenEXR import."""
    py313 = next(iter(sorted(Path.home().glob(".pyenv/versions/3.13*/bin/python3.13"))), None)
    if py313 is None:
        pytest.skip("no Python 3.13 on this machine (pyenv)")
    dist = tmp_path / "dist"
    _build(dist)
    wheel = next(dist.glob("gsgs-*.whl"))
    env = tmp_path / "venv"
    subprocess.run([str(py313), "-m", "venv", str(env)], check=True, timeout=300)
    py = env / "bin" / "python"
    deps = [r for r in _requirements_for(zipfile.ZipFile(wheel), "3.13") if not r.startswith("torch")]
    out = subprocess.run([str(py), "-m", "pip", "install", "--no-deps", str(wheel), *deps],
                         capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    probe = ("import sys, numpy, pycolmap, cv2, OpenEXR, gsgs_engine, gsgs_engine.io, gsgs_engine.cameras, "
             "gsgs_engine.job; print(sys.version_info[:2], numpy.__version__, gsgs_engine.__version__)")
    out = subprocess.run([str(py), "-c", probe], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert out.returncode == 0 and out.stdout.startswith("(3, 13) 2."), out.stdout + out.stderr


# -- the artist's path, in one Blender process (one installed environment for every assertion) ----

def _torch_build() -> str:
    """The default CPU build where PyTorch's CPU index answers; else torch as pip's own index serves it
    (this machine and its CI: download.pytorch.org is not reachable, pip's find-links has the CPU wheel)."""
    import urllib.request

    try:
        urllib.request.urlopen(engine_installer.TORCH_CPU_INDEX + "/torch/", timeout=10).close()
        return "cpu"
    except OSError:
        return "index"


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("install_engine")
    photos = shared_scene("photos_santorini")
    zip_path = _build(tmp / "dist")
    home = tmp / "home"
    home.mkdir()
    pip_cache = subprocess.run([sys.executable, "-m", "pip", "cache", "dir"], capture_output=True, text=True).stdout.strip()
    env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "HOME": str(home),
           "BLENDER_USER_RESOURCES": str(tmp / "blender_user"), "OMP_NUM_THREADS": "2",
           # pip keeps its own settings (index, find-links, certificates) and the machine's download cache
           **{k: v for k, v in os.environ.items() if k.startswith("PIP_") or k in ("SSL_CERT_FILE", "TMPDIR")}}
    if pip_cache and "PIP_CACHE_DIR" not in env:
        env["PIP_CACHE_DIR"] = pip_cache
    torch_build = _torch_build()
    out = subprocess.run([sys.executable, str(REPO / "tests" / "install_engine_run.py"), str(zip_path), str(photos),
                          str(tmp / "jobs"), sys.executable, str(REPO), torch_build],
                         capture_output=True, text=True, timeout=2400, cwd=tmp, env=env)
    line = next((ln for ln in out.stdout.splitlines() if ln.startswith("RESULT ")), None)
    assert line is not None, out.stdout[-4000:] + out.stderr[-4000:]
    result = json.loads(line[len("RESULT "):])
    result["blender_user"] = str(tmp / "blender_user")
    result["torch_build"] = torch_build
    print("install_engine_run: " + json.dumps(result, indent=1))  # install time and disk use, with -s
    return result


def _unchanged(step: dict) -> None:
    assert step["after"]["ok"], step["after"]["report"]  # the previous Engine Python still works
    assert step["after"]["python"] == sys.executable and step["after"]["root"] == str(REPO)
    assert step["leftovers"] == []  # no half-made environment


@pytest.mark.slow
def test_a_bad_package_index_changes_nothing_and_says_why_in_one_line(installed):
    bad = installed["bad_index"]
    assert installed["before"]["ok"], installed["before"]["report"]
    assert bad["raised"] and bad["message"] in bad["raised"]
    assert "\n" not in bad["message"]
    assert "could not reach http://127.0.0.1:9/simple" in bad["message"] and "Package Index" in bad["message"]
    _unchanged(bad)


@pytest.mark.slow
def test_a_cancel_during_the_torch_step_changes_nothing(installed):
    cancel = installed["cancel"]
    assert cancel["step_at_cancel"] == "torch" and cancel["env_existed"]
    assert cancel["state"] == "cancelled" and "\n" not in cancel["message"] and "cancelled" in cancel["message"]
    assert not cancel["env_exists"]
    _unchanged(cancel)


@pytest.mark.slow
def test_install_engine_from_the_package_index(installed):
    inst = installed["install"]
    assert Path(inst["env"]).parent == Path(installed["engines_dir"])
    assert installed["engines_dir"].startswith(installed["blender_user"])  # the extension's user folder
    assert inst["leftovers"] == [Path(inst["env"]).name]
    assert inst["final"]["state"] == "ok" and inst["final"]["warnings"] == [], inst["final"]
    assert list(inst["final"]["step_seconds"]) == [name for name, _ in engine_installer.STEPS]
    assert inst["kernel_built"] and inst["lpips"] == ["lpips_v0.1_alex.safetensors", "lpips_v0.1_vgg.safetensors"]
    after = installed["after_install"]
    assert after["ok"], after["report"]
    assert after["python"] == inst["final"]["python"] and after["root"] == ""
    assert "missing" not in after["report"] and "mismatch" not in after["report"]
    for name in ("torch 2.", "pycolmap 4.", "OpenCV 4.", "backends: "):
        assert name in after["report"], after["report"]
    assert "cpu" in after["report"].split("backends: ")[1]  # the compiled kernel loads
    assert installed["cli"] == [0, 0]  # `gsgs --help` and `python -m gsgs_engine --help` from the wheel


@pytest.mark.slow
def test_photos_to_splats_with_the_installed_engine(installed):
    assert installed["import_photos"] == ["FINISHED"] and installed["cameras"] == 3
    assert installed["train"] == ["FINISHED"]
    assert installed["splats"] > 0 and installed["vertices"] == installed["splats"]
    python = installed["install"]["final"]["python"]
    assert installed["job_pythons"] == {"sfm_job": python, "train_job": python}
    assert '"backend": "cpu"' in json.dumps(installed["metrics"])


def test_preferences_offer_install_engine_with_its_settings(tmp_path):
    from test_blender_addon import _Layout

    from gsgs_blender import engine_install, preferences

    log: list = []
    engine_install.draw_preferences(preferences._FALLBACK, _Layout(log))
    props = [args[1] for name, args, _ in log if name == "prop"]
    assert props == ["install_python", "torch_build", "install_index_url", "torch_index_url"]
    ops = [(args[0], kw.get("text")) for name, args, kw in log if name == "operator"]
    buttons = {"gsgs.install_engine": "Reinstall Engine" if engine_install.installed_engines() else "Install Engine"}
    assert dict(ops[:1]) == buttons
    # registered, the preferences carry the install settings (mixed in) next to their own
    import gsgs_blender

    bpy.ops.wm.read_factory_settings(use_empty=True)
    gsgs_blender.register()
    try:
        rna = set(preferences.GSGS_AddonPreferences.bl_rna.properties.keys())
    finally:
        gsgs_blender.unregister()
    assert {"python_path", "engine_root", "install_python", "torch_build", "install_index_url", "torch_index_url"} <= rna


@pytest.mark.slow
def test_the_ui_timer_follows_an_install_to_its_end(tmp_path, monkeypatch):
    """Interactive Blender's path, with the timer driven directly: while the installer runs, the
    preferences draw its step and a Cancel button; the timer settles it (here an unreachable
    index: a real venv, a real pip) and fires on_finish once; the result is drawn as one line."""
    import time

    from test_blender_addon import _Layout

    from gsgs_blender import engine_install, preferences

    prefs = type("Prefs", (), {**{k: getattr(preferences._FALLBACK, k) for k in dir(preferences._FALLBACK)
                                  if not k.startswith("_")}, "install_index_url": "http://127.0.0.1:9/simple"})()
    # pip sees only the unreachable index: no pip.conf extra index or find-links answers in its place
    monkeypatch.setenv("PIP_CONFIG_FILE", os.devnull)
    monkeypatch.delenv("PIP_FIND_LINKS", raising=False)
    monkeypatch.delenv("PIP_EXTRA_INDEX_URL", raising=False)
    finished = []
    run = engine_install.start(prefs, folder=str(tmp_path), on_finish=finished.append, use_timer=False)
    try:
        with pytest.raises(Exception, match="already running"):
            engine_install.start(prefs, folder=str(tmp_path), use_timer=False)
        while not run.last_event and run.process.poll() is None:
            run.poll()
            time.sleep(0.1)
        log: list = []
        engine_install.draw_preferences(prefs, _Layout(log))
        assert [args[0] for name, args, _ in log if name == "operator"] == ["gsgs.cancel_engine_install"]
        assert any(name == "progress" and kw["text"].startswith("step ") for name, _, kw in log)
        deadline = time.monotonic() + 300
        while engine_install._timer() is not None and time.monotonic() < deadline:
            time.sleep(0.2)
    finally:
        if not run.finished:
            run.cancel()
            run.wait(echo=False)
    assert run.state == "error" and finished == [run] and run.finished_handled
    assert not run.env.exists() and engine_install.installed_engines(str(tmp_path)) == []
    log = []
    engine_install.draw_preferences(prefs, _Layout(log))
    labels = [(kw.get("text"), kw.get("icon")) for name, _, kw in log if name == "label"]
    assert (run.message[:200], "ERROR") in labels and "could not reach" in run.message
    ops = [args[0] for name, args, _ in log if name == "operator"]
    assert ops == ["gsgs.install_engine"]  # nothing installed: no Uninstall
    engine_install.CURRENT.clear()


@pytest.mark.slow
def test_reinstall_replaces_the_engine_and_uninstall_removes_it(installed):
    again, gone = installed["reinstall"], installed["uninstall"]
    assert not again["first_exists"] and again["leftovers"] == [Path(again["second"]).name]
    assert again["python"].startswith(again["second"])
    assert gone["leftovers"] == [] and not gone["second_exists"]
    assert gone["python"] == "python3" and gone["root"] == ""  # the defaults of an installed extension
