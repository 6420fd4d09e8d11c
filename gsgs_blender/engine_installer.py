"""Install the gsgs engine into a new virtual environment (the add-on's Install Engine runs this).

    python engine_installer.py --env DIR --source ENGINE_WHEEL_OR_CHECKOUT --progress FILE
                               [--index-url URL] [--torch auto|cpu|cuda|index] [--torch-index-url URL]

Standard library only: the add-on runs it as a child process with the Python the engine will
use (Blender's own, or one the artist names), so neither Blender nor this script imports torch.
Steps: check the Python version, create the venv, bring pip to >= 24.1 (its `--progress-bar raw`
gives the MB downloaded), torch (the CPU or the CUDA build, reason stated), the engine wheel with
its dependencies (pycolmap, OpenCV, OpenEXR, ...), LPIPS weights, the compiled CPU kernel, an
import check, and last the marker file INSTALLED that makes DIR a finished engine.

Nothing is left half-installed: DIR is new (a name no earlier install used); on a failure, a cancel
(SIGTERM) or an exception DIR is deleted, and only a finished DIR carries INSTALLED. The venv is
never moved after it is made (its scripts name their own path), so "swapping in" the new engine
is the caller pointing Engine Python at DIR's python, once INSTALLED exists.

FILE gets one JSON object a line: {"step", "n", "of", "label", "mb"} while it works, and a last
{"state": "ok" | "error" | "cancelled", "message", "python", "warnings", "seconds"}. The full
output of every command goes to the log (FILE with the suffix .log).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

MARKER = "INSTALLED"
PIP_RAW_PROGRESS = (24, 1)  # pip --progress-bar raw ("Progress X of Y" lines) appeared in pip 24.1
SUPPORTED = ((3, 11), (3, 13))  # the engine's requires-python, >=3.11,<3.14
TORCH_CPU_INDEX = "https://download.pytorch.org/whl/cpu"
# PyPI's Linux torch is the CUDA build; on Windows PyPI has the CPU build only, so CUDA comes from here.
TORCH_CUDA_INDEX_WINDOWS = "https://download.pytorch.org/whl/cu130"
NO_COMPILER_COST = ("the engine trains with its reference (pure torch) rasteriser instead, 10-30x slower per "
                    "step (README, Rasteriser table)")
STEPS = [("python", "check the Python version"), ("venv", "create the virtual environment"),
         ("pip", "bring pip up to date"), ("torch", "install torch"),
         ("engine", "install the engine, pycolmap, OpenCV, OpenEXR"), ("lpips", "fetch the LPIPS weights"),
         ("kernel", "build the compiled CPU kernel"), ("verify", "import everything once")]


class StepError(Exception):
    """A step failed: the message is the one line the artist sees."""


class Cancelled(Exception):
    pass


def env_python(env: Path) -> Path:
    return env / ("Scripts/python.exe" if os.name == "nt" else "bin/python")


def nvidia_gpu() -> str | None:
    """The first NVIDIA GPU's name (`nvidia-smi -L`), or None when there is none or no driver."""
    smi = shutil.which("nvidia-smi")
    if smi is None:
        return None
    try:
        out = subprocess.run([smi, "-L"], capture_output=True, text=True, timeout=20).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    m = re.search(r"GPU \d+: (.+?)( \(UUID|$)", out, re.M)
    return m.group(1).strip() if m else None


def torch_choice(build: str, torch_index: str, gpu: str | None) -> tuple[str | None, str]:
    """(index URL for the torch step or None for the package index, the sentence that says why)."""
    if build == "auto":
        build = "cuda" if gpu else "cpu"
        why = f"an NVIDIA GPU was found ({gpu})" if gpu else "no NVIDIA GPU was found (nvidia-smi lists none)"
    else:
        why = "the Torch Build preference says so"
    if build == "index":
        return torch_index or None, f"torch as the package index serves it ({why})"
    if build == "cpu":
        url = torch_index or TORCH_CPU_INDEX
        return url, (f"the CPU build of torch from {url}: {why} (torch 2.13 on Linux: a 0.19 GB wheel; the CUDA "
                     "build and its CUDA libraries are about 2.9 GB)")
    url = torch_index or (TORCH_CUDA_INDEX_WINDOWS if os.name == "nt" else None)
    return url, f"the CUDA build of torch from {url or 'the package index'}: {why}"


def engine_requirements(source: Path) -> tuple[str, str]:
    """(torch requirement, Requires-Python) from the engine wheel's METADATA or the checkout's pyproject."""
    if source.suffix == ".whl":
        with zipfile.ZipFile(source) as zf:
            name = next(n for n in zf.namelist() if n.endswith(".dist-info/METADATA"))
            meta = zf.read(name).decode()
        torch = re.search(r"^Requires-Dist: (torch\b[^;\n]*)", meta, re.M)
        py = re.search(r"^Requires-Python: (.+)$", meta, re.M)
        return (torch.group(1).strip() if torch else "torch"), (py.group(1).strip() if py else "")
    text = (source / "pyproject.toml").read_text()
    torch = re.search(r'"(torch[=<>!~ ][^"]*)"', text)
    py = re.search(r'^requires-python\s*=\s*"([^"]+)"', text, re.M)
    return (torch.group(1) if torch else "torch"), (py.group(1) if py else "")


def python_allowed(spec: str, version: tuple[int, int]) -> bool:
    """A minimal check of a Requires-Python like '<3.14,>=3.11' against major.minor."""
    for part in filter(None, (p.strip() for p in spec.split(","))):
        m = re.fullmatch(r"(>=|<=|<|>|==)\s*(\d+)\.(\d+)", part)
        if not m:
            continue
        other = (int(m.group(2)), int(m.group(3)))
        ok = {">=": version >= other, "<=": version <= other, "<": version < other, ">": version > other,
              "==": version == other}[m.group(1)]
        if not ok:
            return False
    return True


def compiler() -> str | None:
    """The C++ compiler torch's extension builder would use, or None."""
    names = [os.environ["CXX"]] if os.environ.get("CXX") else []
    names += ["cl"] if os.name == "nt" else ["c++", "g++", "clang++"]
    return next((shutil.which(n) for n in names if shutil.which(n)), None)


# pip's words when the index cannot be reached, the most telling first
OFFLINE_SIGNS = ("Connection refused", "Name or service not known", "Temporary failure in name resolution",
                 "Could not resolve host", "Network is unreachable", "No route to host", "timed out",
                 "Failed to establish a new connection", "NewConnectionError", "Max retries exceeded")


def pip_failure(step: str, output: str, index: str | None) -> str:
    """One line: what pip could not do, and the fix."""
    errors = [ln[len("ERROR: "):].strip() for ln in output.splitlines() if ln.startswith("ERROR: ")]
    errors = [e for e in errors if not e.startswith("Ignored the following")] or errors
    offline = next((m for m in (re.search(p, output) for p in OFFLINE_SIGNS) if m), None)
    where = index or "pip's configured package index"
    cause = errors[0] if errors else (output.strip().splitlines() or ["no output"])[-1]
    if offline:
        return (f"{step}: pip could not reach {where} ({offline.group(0)}): {cause}. Fix: connect to the "
                "network or set Package Index to a reachable mirror, then Install Engine again; or point "
                "Engine Python at an existing environment with the engine")
    if "No space left" in output:
        return f"{step}: the disk is full ({cause}). Fix: free space, then Install Engine again"
    return (f"{step}: pip failed: {cause}. Fix: set Package Index / Torch Index to an index that has it, "
            "then Install Engine again; or point Engine Python at an existing environment with the engine")


class Installer:
    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.env = Path(args.env).resolve()
        self.progress = Path(args.progress)
        self.log_path = self.progress.with_suffix(".log")
        self.python = env_python(self.env)
        self.warnings: list[str] = []
        self.mb = 0.0
        self.step = ("", 0, "")
        self.child: subprocess.Popen | None = None
        self.cancelled = False
        self.last_emit = 0.0
        self.raw_progress = False
        self.step_seconds: dict[str, float] = {}
        self.step_start = time.monotonic()

    # -- output -----------------------------------------------------------------------------------
    def emit(self, force: bool = False, **extra) -> None:
        now = time.monotonic()
        if not force and now - self.last_emit < 0.5:
            return
        self.last_emit = now
        name, n, label = self.step
        event = {"step": name, "n": n, "of": len(STEPS), "label": label, "mb": round(self.mb, 1), **extra}
        with open(self.progress, "a", encoding="utf-8") as fh:
            fh.write(json.dumps(event) + "\n")

    def log(self, text: str) -> None:
        with open(self.log_path, "a", encoding="utf-8") as fh:
            fh.write(text if text.endswith("\n") else text + "\n")

    def begin(self, name: str) -> None:
        self.end_step()
        n = next(i for i, (key, _) in enumerate(STEPS, 1) if key == name)
        self.step = (name, n, dict(STEPS)[name])
        self.log(f"== step {n}/{len(STEPS)} {name}: {dict(STEPS)[name]} ({time.ctime()})")
        self.emit(force=True)

    def end_step(self) -> None:
        if self.step[0]:
            self.step_seconds[self.step[0]] = round(time.monotonic() - self.step_start, 1)
        self.step_start = time.monotonic()

    # -- running commands -------------------------------------------------------------------------
    def run(self, argv: list[str], env: dict | None = None) -> tuple[int, str]:
        """Run argv, its output into the log line by line; MB downloaded from pip's raw progress."""
        self.log("$ " + " ".join(argv))
        if self.cancelled:
            raise Cancelled()
        lines: list[str] = []
        done_bytes = 0.0  # finished downloads of this command
        current = 0.0
        self.child = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                      errors="replace", stdin=subprocess.DEVNULL, env=env or self.child_env())
        base = self.mb
        with open(self.log_path, "a", encoding="utf-8") as log:
            for line in self.child.stdout:
                m = re.match(r"Progress (\d+) of (\d+)", line)
                if m:
                    got, total = int(m.group(1)), int(m.group(2))
                    current = got
                    if got >= total:
                        done_bytes, current = done_bytes + total, 0.0
                    self.mb = base + (done_bytes + current) / 1e6
                    self.emit()
                    continue
                lines.append(line)
                log.write(line)
        rc = self.child.wait()
        self.child = None
        if self.cancelled:
            raise Cancelled()
        return rc, "".join(lines)

    def child_env(self) -> dict:
        env = dict(os.environ)
        for key in ("PYTHONHOME", "PYTHONPATH", "PYTHONNOUSERSITE", "VIRTUAL_ENV"):
            env.pop(key, None)  # Blender's settings for its own Python would break the venv's
        env["PYTHONUNBUFFERED"] = "1"
        env["PIP_DISABLE_PIP_VERSION_CHECK"] = "1"
        return env

    def pip(self, step: str, *args: str, index: str | None = None) -> None:
        argv = [str(self.python), "-m", "pip", "install", "--progress-bar", "raw" if self.raw_progress else "off"]
        if index:
            argv += ["--index-url", index]
        rc, out = self.run(argv + list(args))
        if rc != 0:
            raise StepError(pip_failure(step, out, index or self.args.index_url))

    # -- the steps --------------------------------------------------------------------------------
    def install(self) -> dict:
        start = time.monotonic()
        source = Path(self.args.source)
        index = self.args.index_url or None
        self.begin("python")
        if not (source.is_file() or (source / "pyproject.toml").is_file()):
            raise StepError(f"engine: {source} is neither the engine wheel nor a checkout; rebuild the "
                            "extension zip with `make extension` and install it again")
        torch_req, requires = engine_requirements(source)
        version = sys.version_info[:2]
        if not python_allowed(requires, version):
            raise StepError(f"python: {sys.executable} is Python {version[0]}.{version[1]}, the engine needs "
                            f"{requires}; name another Python in Engine Base Python (3.11 to 3.13)")
        self.begin("venv")
        if self.env.exists():
            raise StepError(f"venv: {self.env} exists already; remove it or install again")
        rc, out = self.run([sys.executable, "-m", "venv", str(self.env)])
        if rc != 0 or not self.python.exists():
            tail = (out.strip().splitlines() or ["no output"])[-1]
            raise StepError(f"venv: {sys.executable} -m venv failed ({tail}); name another Python in Engine "
                            "Base Python, or point Engine Python at an existing environment with the engine")
        self.begin("pip")
        rc, out = self.run([str(self.python), "-m", "pip", "--version"])
        m = re.search(r"pip (\d+)\.(\d+)", out)
        have = (int(m.group(1)), int(m.group(2))) if m else (0, 0)
        if have < PIP_RAW_PROGRESS:
            argv = [str(self.python), "-m", "pip", "install", "--upgrade", "pip>=24.1"]
            rc, out = self.run(argv + (["--index-url", index] if index else []))
            if rc != 0:
                raise StepError(pip_failure("pip", out, index))
        self.raw_progress = True
        self.begin("torch")
        torch_index, why = torch_choice(self.args.torch, self.args.torch_index_url, nvidia_gpu())
        self.log(f"torch: {why}")
        self.emit(force=True, torch=why)
        self.pip("torch", torch_req, index=torch_index or index)
        self.begin("engine")
        self.pip("engine", str(source), index=index)
        self.begin("lpips")
        rc, out = self.run([str(self.python), "-m", "gsgs_engine.lpips.fetch"])
        if rc != 0:
            tail = (out.strip().splitlines() or ["no output"])[-1]
            self.warnings.append(f"LPIPS weights not fetched ({tail}): metrics.json records lpips null; "
                                 f"run `{self.python} -m gsgs_engine.lpips.fetch` when online")
        self.begin("kernel")
        cxx = compiler()
        if cxx is None:
            self.warnings.append("no C++ compiler was found (c++, g++, clang++ or cl; CXX unset): "
                                 f"{NO_COMPILER_COST}. Install one, then Reinstall Engine")
        else:
            rc, out = self.run([str(self.python), "-m", "gsgs_engine", "build-ext"])
            if rc != 0:
                tail = (out.strip().splitlines() or ["no output"])[-1]
                self.warnings.append(f"the compiled CPU kernel did not build with {cxx} ({tail}): {NO_COMPILER_COST}")
        self.begin("verify")
        probe = ("import json, torch, pycolmap, cv2, OpenEXR, gsgs_engine; print('GSGS_VERSIONS ' + json.dumps("
                 "{'torch': torch.__version__, 'pycolmap': pycolmap.__version__, 'cv2': cv2.__version__, "
                 "'gsgs_engine': gsgs_engine.__version__, 'cuda': torch.version.cuda}))")
        rc, out = self.run([str(self.python), "-c", probe])
        line = next((ln for ln in out.splitlines() if ln.startswith("GSGS_VERSIONS ")), None)
        if rc != 0 or line is None:
            tail = (out.strip().splitlines() or ["no output"])[-1]
            raise StepError(f"verify: the new environment cannot import the engine ({tail}); see {self.log_path}")
        versions = json.loads(line.split(" ", 1)[1])
        self.end_step()
        record = {"python": str(self.python), "base_python": sys.executable, "torch_build": why,
                  "versions": versions, "warnings": self.warnings, "seconds": round(time.monotonic() - start, 1),
                  "downloaded_mb": round(self.mb, 1), "step_seconds": self.step_seconds, "installed": time.strftime("%Y-%m-%d %H:%M:%S")}
        (self.env / MARKER).write_text(json.dumps(record, indent=1))
        return record

    def on_sigterm(self, signum, frame) -> None:
        self.cancelled = True
        if self.child is not None and self.child.poll() is None:
            self.child.terminate()
        raise Cancelled()

    def main(self) -> int:
        self.progress.parent.mkdir(parents=True, exist_ok=True)
        signal.signal(signal.SIGTERM, self.on_sigterm)
        start = time.monotonic()
        final: dict
        try:
            record = self.install()
            final = {"state": "ok", "message": f"engine installed in {self.env} ({record['seconds']:.0f} s, "
                     f"{record['downloaded_mb']:.0f} MB downloaded); {record['torch_build']}",
                     "python": str(self.python), "warnings": self.warnings, "versions": record["versions"],
                     "step_seconds": self.step_seconds}
        except Cancelled:
            final = {"state": "cancelled", "message": "Install Engine cancelled; nothing was changed"}
        except StepError as exc:
            final = {"state": "error", "message": f"Install Engine failed at {exc} (log: {self.log_path})"}
        except Exception as exc:  # noqa: BLE001 (one line for the artist; the traceback goes to the log)
            import traceback

            self.log(traceback.format_exc())
            final = {"state": "error", "message": f"Install Engine failed: {type(exc).__name__}: {exc} "
                                                  f"(log: {self.log_path})"}
        finally:
            signal.signal(signal.SIGTERM, signal.SIG_IGN)
            if self.child is not None:  # a cancel or an error mid-command: the child goes first
                self.child.terminate()
                try:
                    self.child.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    self.child.kill()
                    self.child.wait()
        if final["state"] != "ok" and self.env.exists():
            shutil.rmtree(self.env, ignore_errors=True)
        final["seconds"] = round(time.monotonic() - start, 1)
        self.log(f"== {final['state']}: {final['message']}")
        self.emit(force=True, **final)
        print(final["message"])
        for warning in final.get("warnings", []):
            print("warning: " + warning)
        return 0 if final["state"] == "ok" else 1


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", required=True, help="the new environment's folder (must not exist)")
    parser.add_argument("--source", required=True, help="the engine wheel (gsgs-*.whl) or a checkout")
    parser.add_argument("--progress", required=True, help="JSON-lines progress file (the log goes next to it)")
    parser.add_argument("--index-url", default="", help="package index for every pip step (default: pip's own)")
    parser.add_argument("--torch", choices=["auto", "cpu", "cuda", "index"], default="auto",
                        help="torch build: auto (CUDA with an NVIDIA GPU, else CPU), cpu, cuda, or index "
                             "(whatever the package index serves)")
    parser.add_argument("--torch-index-url", default="", help="index for the torch step (default: PyTorch's "
                                                              "CPU index for cpu, the package index for cuda)")
    return parser.parse_args(argv)


if __name__ == "__main__":
    sys.exit(Installer(parse_args()).main())
