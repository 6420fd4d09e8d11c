"""`gsgs build-ext`: compile the CPU rasteriser once into its cache (see gsgs_engine.render.cpu_backend)."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from gsgs_engine.render import cpu_backend

    cpu_backend.add_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from gsgs_engine.render import cpu_backend

    return cpu_backend.run(args)
