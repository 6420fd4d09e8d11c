"""Shared test fixtures. Real data lives in ../shared/data; tests that need it skip clearly."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

# Before torch is imported anywhere: idle OpenMP workers sleep rather than spin (see gsgs_engine.cli).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("GSGS_SHARED_DATA", REPO.parent / "shared" / "data"))


def shared_scene(name: str) -> Path:
    """Path of a scene in ../shared/data, or skip the test saying why."""
    path = SHARED_DATA / name
    if not path.exists():
        pytest.skip(f"real data {path} is absent (a user's checkout has no ../shared); set GSGS_SHARED_DATA")
    return path


@pytest.fixture(autouse=True, scope="session")
def _private_timings_log(tmp_path_factory):
    # The add-on learns its time estimate from finished jobs (gsgs_blender.train_estimate): tests write their own log.
    path = tmp_path_factory.mktemp("timings") / "train_timings.jsonl"
    old = os.environ.get("GSGS_TIMINGS")
    os.environ["GSGS_TIMINGS"] = str(path)
    yield path
    if old is None:
        os.environ.pop("GSGS_TIMINGS", None)
    else:
        os.environ["GSGS_TIMINGS"] = old


@pytest.fixture(autouse=True, scope="session")
def _no_init_cache():
    # The initialisation's cache across jobs (gsgs_engine.init.cache) would let one test's triangulation or dense init
    # answer another's (and skip a monkeypatched computation): off for the suite, child processes included; the cache's
    # own tests point it at a folder of their own.
    old = os.environ.get("GSGS_INIT_CACHE")
    os.environ["GSGS_INIT_CACHE"] = "off"
    yield
    if old is None:
        os.environ.pop("GSGS_INIT_CACHE", None)
    else:
        os.environ["GSGS_INIT_CACHE"] = old


@pytest.fixture(autouse=True, scope="session")
def _few_threads():
    # The CI machine has 2 cores; keep torch from oversubscribing when tests run.
    try:
        import torch
    except ImportError:  # the add-on tests run without torch
        yield
        return
    torch.set_num_threads(min(2, os.cpu_count() or 1))
    yield
