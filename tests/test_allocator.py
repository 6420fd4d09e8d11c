"""The engine keeps freed memory for reuse (gsgs_engine/allocator.py): measured as page faults, in fresh processes."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

FAULTS = r"""
import resource, sys, torch
from gsgs_engine.allocator import keep_freed_memory
print("tuned", keep_freed_memory())
def step():  # a 40 MB buffer (e.g. the SH gradients of 200k Gaussians) filled and freed, as in every step
    e = torch.empty(10_000_000).fill_(1.0)
    return float(e[0])
for _ in range(5):
    step()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(200):
    step()
print("faults", resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _faults(env_extra: dict) -> tuple[str, int]:
    env = {**os.environ, "PYTHONPATH": str(REPO), **env_extra}
    done = subprocess.run([sys.executable, "-c", FAULTS], capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 0, done.stderr
    lines = dict(line.split(" ", 1) for line in done.stdout.splitlines())
    return lines["tuned"], int(lines["faults"])


@pytest.mark.skipif(sys.platform != "linux", reason="malloc's thresholds are glibc's (Linux)")
def test_freed_memory_is_reused_instead_of_faulted_in_again():
    tuned, faults = _faults({})
    assert tuned == "True"
    untuned, faults_default = _faults({"GSGS_MALLOC_TUNING": "0"})
    assert untuned == "False"
    # 200 such steps: with glibc's defaults a block over 32 MB is mapped afresh each time (about 9,800 page faults
    # each), tuned mostly the first step's memory again
    assert 20 * faults < faults_default and faults_default > 1_000_000, (faults, faults_default)  # 49k vs 1.95M


def test_the_command_line_applies_it(monkeypatch, tmp_path, capsys):
    from gsgs_engine import allocator, cli

    calls = []
    monkeypatch.setattr(allocator, "keep_freed_memory", lambda: calls.append(1) or True)
    assert cli.main(["eval", str(tmp_path / "no-such-run"), "--data", str(tmp_path / "no-data")]) == 2  # fails fast
    assert calls == [1]


@pytest.mark.parametrize("module, argv", [
    ("gsgs_engine.bench.rasterizer", ["--cell", "{}"]),
    ("gsgs_engine.bench.train_step", ["--cell", "{}"]),
    ("gsgs_engine.bench.accuracy_cell", ["DATA", "--out", "OUT", "--settings", "{}"]),
])
def test_the_benchmarks_cell_workers_apply_it_first(monkeypatch, module, argv):
    """A cell worker (`python -m MODULE`) times what `gsgs train` runs: the same malloc settings, set before the cell
    builds anything."""
    import importlib

    from gsgs_engine import allocator

    class Applied(Exception):
        pass

    def keep():
        raise Applied

    monkeypatch.setattr(allocator, "keep_freed_memory", keep)
    worker = importlib.import_module(module)
    main = getattr(worker, "_cell_main", None)
    with pytest.raises(Applied):
        main([module, *argv]) if main is not None else worker.main(argv)
