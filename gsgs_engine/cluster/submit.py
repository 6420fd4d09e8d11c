"""`--ray ADDRESS` for the commands: what of a `gsgs train` or a job folder travels, and how it comes back.

A train run sends its scene folder and (to resume) the newest checkpoint; a job folder sends job.json
with every path it names made relative to folders sent beside it. The worker runs the same engine
command; the run folder / job folder here receives progress, checkpoints, status and results.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from pathlib import Path

from gsgs_engine import GsgsError

DEFAULT_RETRIES = 2
JOB_STATE = ("result", "checkpoints", "progress.jsonl", "log.txt", "status.json", "bench_log.txt")
RAY_OPTIONS = ("--ray", "--ray-cpus", "--ray-gpus", "--ray-retries")


def add_ray_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("Ray cluster (docs/cluster.md)")
    group.add_argument("--ray", metavar="ADDRESS", default=None,
                       help="run on the Ray cluster at ADDRESS (HOST:PORT of `ray start --head`, or ray://HOST:10001); "
                            "inputs are sent, results come back here")
    group.add_argument("--ray-cpus", type=float, default=1.0, help="CPUs a run asks the cluster for (default 1; "
                                                                   "the engine uses as many threads)")
    group.add_argument("--ray-gpus", type=float, default=None,
                       help="GPUs a run asks for (default 1 with --backend cuda, else 0)")
    group.add_argument("--ray-retries", type=int, default=DEFAULT_RETRIES,
                       help=f"times a run lost with its worker starts again from its last checkpoint (default "
                            f"{DEFAULT_RETRIES})")


def resources(args: argparse.Namespace, backend: str | None) -> tuple[float, float]:
    if args.ray_cpus <= 0:
        raise GsgsError(f"--ray-cpus must be positive (got {args.ray_cpus})")
    if args.ray_retries < 0:
        raise GsgsError(f"--ray-retries must be 0 or more (got {args.ray_retries})")
    gpus = args.ray_gpus if args.ray_gpus is not None else (1.0 if backend == "cuda" else 0.0)
    if gpus < 0:
        raise GsgsError(f"--ray-gpus must be 0 or more (got {args.ray_gpus})")
    return float(args.ray_cpus), float(gpus)


@dataclass
class ClusterCells:
    """Where and with what a benchmark grid's cells run on a Ray cluster (one job a cell)."""

    address: str
    cpus: float = 1.0
    gpus: float = 0.0
    retries: int = DEFAULT_RETRIES


def cluster_cells(args: argparse.Namespace) -> ClusterCells:
    """The grid's --ray options, the address checked before anything is sent."""
    from gsgs_engine.cluster.address import check_address

    check_address(args.ray)
    cpus, gpus = resources(args, None)
    return ClusterCells(args.ray, cpus, gpus, args.ray_retries)


def thread_env(num_cpus: float) -> dict:
    threads = str(max(1, int(num_cpus)))
    return {"OMP_NUM_THREADS": threads, "MKL_NUM_THREADS": threads}


def option_tokens(argv: list[str], parser: argparse.ArgumentParser, command: str) -> tuple[list[str], list[str]]:
    """(positionals, option tokens) of the command line after `command`, options kept with their values."""
    tokens = list(argv)
    if command in tokens:
        tokens = tokens[tokens.index(command) + 1:]
    positionals, options = [], []
    i = 0
    while i < len(tokens):
        tok = tokens[i]
        if tok.startswith("-") and tok != "-":
            name = tok.split("=", 1)[0]
            action = parser._option_string_actions.get(name)
            takes_value = action is not None and action.nargs != 0 and "=" not in tok
            group = tokens[i:i + 2] if takes_value else [tok]
            options.append(group)
            i += len(group)
        else:
            positionals.append(tok)
            i += 1
    return positionals, options


def remote_train_argv(argv: list[str], parser: argparse.ArgumentParser, data_label: str) -> list[str]:
    """The worker's `gsgs train` argv: the data and --out replaced by the sent folders, the cluster options
    and --resume / --overwrite dropped (the worker's folder is fresh; resuming is decided here)."""
    _, options = option_tokens(argv, parser, "train")
    drop = set(RAY_OPTIONS) | {"--out", "--resume", "--overwrite"}
    kept = [tok for group in options if group[0].split("=", 1)[0] not in drop for tok in group]
    return ["train", "{work}/data", "--out", "{work}/out", "--data-label", data_label, *kept]


def train_on_cluster(args: argparse.Namespace, argv: list[str], out: Path, resume_command: str) -> int:
    """`gsgs train ... --ray ADDRESS`: the run folder `out` was claimed here; the worker trains.
    `resume_command`: how to continue from here (the worker's message names its own folders)."""
    from gsgs_engine.cluster.remote import RemoteCommand, folder_archive, outgoing_state
    from gsgs_engine.job import Job

    data = Path(args.data)
    if not data.is_dir():
        raise GsgsError(f"{data}: --ray sends a scene folder; this is not one")
    cpus, gpus = resources(args, args.backend)
    base = remote_train_argv(argv, args._parser, str(args.data))
    _, has_ckpt = outgoing_state(out)
    resume = bool(args.resume and has_ckpt)
    command = RemoteCommand(argv=base + (["--resume"] if resume else []), inputs={"data": folder_archive(data)},
                            out="out", local_out=out, resume_argv=lambda ckpt: base + (["--resume"] if ckpt else []),
                            num_cpus=cpus, num_gpus=gpus, env=thread_env(cpus), label=f"gsgs train {data}")
    job = Job(root=out, spec={"task": "train"})
    job.set_status("running", f"training {args.data} on the Ray cluster at {args.ray}")
    rc = _run(args.ray, command, job, resume, args.ray_retries)
    status = job.status() or {}
    if status.get("state") == "cancelled":
        job.set_status("cancelled", f"cancelled on the Ray cluster; resume with: {resume_command}",
                       remote=status.get("remote"))
        print(f"gsgs: cancelled; resume with: {resume_command}", file=sys.stderr)
    return rc


def _run(address: str, command, job, ship_state: bool, retries: int, echo=None, on_start=None) -> int:
    from gsgs_engine.cluster.remote import run_remote

    try:
        rc = run_remote(address, command, retries=retries, cancel_file=job.cancel_path, ship_state=ship_state,
                        echo=echo, on_start=on_start)
    except KeyboardInterrupt:  # a second interrupt while the remote run was saving its checkpoint
        job.set_status("cancelled", "cancelled; the remote run was stopped")
        return 130
    except GsgsError as exc:
        job.set_status("error", str(exc))
        raise
    status = job.status() or {}
    if status.get("state") in (None, "running"):
        job.set_status("error", f"the remote engine exited with code {rc} without a final status; see {job.log_path}")
    return rc


def job_paths(spec: dict, root: Path) -> tuple[dict, dict[str, Path]]:
    """(job.json rewritten for the worker, {input name: local path}) for the paths a job's data names:
    data.path / data.source / data.photos (folders) and data.points / data.cameras[*].image (files).
    Paths inside the job folder stay relative; the others travel as folders beside it."""
    spec = json.loads(json.dumps(spec))
    data = spec.get("data") or {}
    sends: dict[str, Path] = {}
    root = Path(root).resolve()

    def local(p) -> Path:
        p = Path(p)
        return (p if p.is_absolute() else root / p).resolve()

    def inside(p: Path) -> str | None:
        try:
            return p.relative_to(root).as_posix() or "."
        except ValueError:
            return None

    for key in ("path", "source", "photos"):
        if isinstance(data.get(key), str):
            p = local(data[key])
            rel = inside(p)
            if rel is None:
                if not p.is_dir():
                    raise GsgsError(f"{root / 'job.json'}: data.{key} {p} is not a folder; nothing to send")
                sends[f"in_{key}"] = p
                rel = f"../in_{key}"
            data[key] = rel
    files: dict[str, Path] = {}

    def file_ref(p) -> str:
        path = local(p)
        rel = inside(path)
        if rel is not None:
            return rel
        if not path.is_file():
            raise GsgsError(f"{root / 'job.json'}: {path} is not a file; nothing to send")
        name = f"{len(files):04d}_{path.name}"
        files[name] = path
        return f"../in_files/{name}"

    if isinstance(data.get("points"), str):
        data["points"] = file_ref(data["points"])
    for cam in data.get("cameras") or []:
        if isinstance(cam, dict) and isinstance(cam.get("image"), str):
            cam["image"] = file_ref(cam["image"])
    spec["data"] = data
    if files:
        sends["in_files"] = files  # type: ignore[assignment]
    return spec, sends


def job_on_cluster(job_dir: Path, address: str, num_cpus: float = 1.0, num_gpus: float = 0.0,
                   retries: int = DEFAULT_RETRIES, echo=None) -> int:
    """`gsgs run-job JOB --ray ADDRESS`: job.json and what it names go out, the job folder fills here."""
    from gsgs_engine.cluster.remote import RemoteCommand, folder_archive, outgoing_state
    from gsgs_engine.cluster.worker import pack
    from gsgs_engine.job import Job

    job = Job.open(job_dir)
    spec, sends = job_paths(job.spec, job.root)
    if num_gpus == 0 and (spec.get("settings") or {}).get("backend") == "cuda":
        num_gpus = 1.0
    inputs = {"job": folder_archive(job.root, exclude=JOB_STATE,
                                    replace={"job.json": json.dumps(spec, indent=2).encode()})}
    for name, path in sends.items():
        if isinstance(path, dict):
            inputs[name] = pack({}, {n: p.read_bytes() for n, p in path.items()})
        else:
            inputs[name] = folder_archive(path)
    _, has_ckpt = outgoing_state(job.root)
    argv = ["run-job", "{work}/job"]
    command = RemoteCommand(argv=argv, inputs=inputs, out="job", local_out=job.root, resume_argv=lambda _: argv,
                            no_sync=("job.json",), num_cpus=num_cpus, num_gpus=num_gpus, env=thread_env(num_cpus),
                            label=f"job {job.root}")
    job.set_status("running", f"{job.task} on the Ray cluster at {address}")
    worker: dict = {}
    rc = _run(address, command, job, has_ckpt, retries, echo=echo, on_start=worker.update)
    if worker.get("work"):
        localise_paths(job.root / "result" / "cameras.json", worker["work"],
                       {"job": job.root, **{k: v for k, v in sends.items() if isinstance(v, Path)}})
    return rc


def localise_paths(cameras_json: Path, remote_work: str, folders: dict[str, Path]) -> None:
    """An SfM result names its photos by absolute path; those the worker wrote point into its own folders
    ({remote_work}/NAME/...), which here are `folders[NAME]`."""
    if not cameras_json.is_file():
        return
    from gsgs_engine.job import write_json_atomic

    entries = json.loads(cameras_json.read_text())
    prefix = remote_work.rstrip("/") + "/"
    for entry in entries if isinstance(entries, list) else []:
        image = entry.get("image") if isinstance(entry, dict) else None
        if isinstance(image, str) and image.startswith(prefix):
            name, _, rest = image[len(prefix):].partition("/")
            if name in folders:
                entry["image"] = str(Path(folders[name]) / rest)
    write_json_atomic(cameras_json, entries)


def echo_to(stream=None):
    """An `echo` for run_remote that writes the engine's console output to `stream` (default stderr)."""
    stream = stream or sys.stderr
    return lambda text: (stream.write(text), stream.flush())
