"""`gsgs` / `python -m gsgs_engine`: one entry point, one module per subcommand.

Each command module exposes `add_arguments(parser)` and `run(args) -> int`; modules are
imported only when their command runs, so `gsgs --help` stays fast and torch-free.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from gsgs_engine import GsgsError, __version__

# name -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "train": ("gsgs_engine.commands.train", "train a Gaussian-splat scene from sparse views (the main job)"),
    "eval": ("gsgs_engine.commands.eval", "re-evaluate a trained result on a scene's test views"),
    "sfm": ("gsgs_engine.commands.sfm", "photos -> cameras + sparse points (pycolmap)"),
    "run-job": ("gsgs_engine.commands.run_job", "run a job folder written by the Blender add-on or a script"),
    "build-ext": ("gsgs_engine.commands.build_ext", "build the compiled CPU rasteriser"),
}
BENCHMARKS: dict[str, tuple[str, str]] = {
    "rasterizer": ("gsgs_engine.bench.rasterizer", "forward / backward time and memory of each rasteriser backend"),
    "train-step": ("gsgs_engine.bench.train_step", "ms per training step on real scenes, old vs new CPU kernel, "
                   "with a profile"),
    "accuracy": ("gsgs_engine.bench.accuracy", "what accuracy costs in time: a grid of settings, table and Pareto plot"),
    "sparse": ("gsgs_engine.bench.sparse", "the sparse-view protocols (LLFF 3 views, NeRF-synthetic 8 views): "
               "variants x scenes x seeds, mean +- std"),
    "sfm": ("gsgs_engine.bench.sfm_poses", "camera poses from sparse photo subsets against known poses"),
    "dynamic": ("gsgs_engine.bench.dynamic", "4D vs static baselines on the rendered dynamic validation scene"),
    "mvs-points": ("gsgs_engine.bench.mvs_points", "dense (MVS) initialisation: seconds and point accuracy on the "
                   "sparse-view protocols' training views, one JSON line per scene"),
    "dense-init": ("gsgs_engine.bench.dense_init", "one cell: plain 3DGS from the SfM points vs from the dense (MVS) "
                   "initialisation"),
    "machine": ("gsgs_engine.bench.machine_speed", "this machine's speed on one fixed render (one JSON line), for the "
                "add-on's training-time estimate"),
    "pseudo-targets": ("gsgs_engine.bench.pseudo_targets", "warp-inpaint pseudo targets vs the render at held-out "
                       "views of a trained result"),
}


def _add_command(subparsers, name: str, module: str, help_text: str) -> None:
    parser = subparsers.add_parser(name, help=help_text, description=help_text)
    mod = importlib.import_module(module)
    mod.add_arguments(parser)
    parser.set_defaults(_run=mod.run)


def build_parser(argv: list[str]) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="gsgs", description="Generative Sparse-view Gaussian Splatting")
    parser.add_argument("--version", action="version", version=f"gsgs {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    # Only the chosen command's module is imported (they may pull in heavy dependencies).
    wanted = next((a for a in argv if not a.startswith("-")), None)
    for name, (module, help_text) in COMMANDS.items():
        if name == wanted:
            _add_command(sub, name, module, help_text)
        else:
            sub.add_parser(name, help=help_text, add_help=False)
    bench = sub.add_parser("bench", help="measured benchmarks (print a table, write JSON)")
    bench_sub = bench.add_subparsers(dest="benchmark", metavar="BENCHMARK")
    bench_wanted = argv[argv.index("bench") + 1] if wanted == "bench" and len(argv) > argv.index("bench") + 1 else None
    for name, (module, help_text) in BENCHMARKS.items():
        if name == bench_wanted:
            _add_command(bench_sub, name, module, help_text)
        else:
            bench_sub.add_parser(name, help=help_text, add_help=False)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    args._argv = argv  # commands that re-issue themselves elsewhere (--ray) read their own flags from it
    run = getattr(args, "_run", None)
    if run is None:
        parser.print_help()
        return 0 if not argv else 2
    from gsgs_engine.allocator import keep_freed_memory
    from gsgs_engine.write_errors import describe_os_error, sigterm_interrupts

    keep_freed_memory()  # a step's tensors reuse the previous step's memory (allocator.py)
    try:
        with sigterm_interrupts():  # SIGTERM unwinds like Ctrl-C: status.json says cancelled, workers stop
            return int(run(args) or 0)
    except GsgsError as exc:
        print(f"gsgs: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # a write into a read-only / full / mistyped place (reads check their paths first)
        print(f"gsgs: error: {describe_os_error(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("gsgs: interrupted", file=sys.stderr)
        return 130
