"""Which machine a run's numbers came from: recorded in every metrics.json and in `gsgs bench sparse`'s tables.

The same job trains a different model on another processor: the math libraries (MKL's calls in the dense
initialisation's plane sweep, among others) take other code paths on AVX-512 than on AVX2 and round differently, and
a protocol cell's PSNR moves by up to a quarter of a dB with nothing else changed (docs/sparse_techniques.md, "One
cell's PSNR under rounding alone"). Comparing cells from two machines then measures the machines, so each run says
which it ran on, and the benchmark table says when its cells came from more than one.
"""

from __future__ import annotations

import os
import platform

# environment switches that change which code paths (and so which roundings) a run takes
ROUNDING_ENV = ("MKL_CBWR", "MKL_ENABLE_INSTRUCTIONS", "ATEN_CPU_CAPABILITY", "ONEDNN_MAX_CPU_ISA",
                "GSGS_TILE_VARIANT", "GSGS_NO_FMA")


def cpu_model() -> str:
    """The processor's model name (/proc/cpuinfo on Linux), else what `platform` knows, else "unknown"."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                key, _, value = line.partition(":")
                if key.strip() in ("model name", "Processor", "cpu model") and value.strip():
                    return " ".join(value.split())
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown"


def machine_record() -> dict:
    """JSON-ready: processor, the instruction set torch's CPU kernels dispatch to, threads, GPU, rounding switches."""
    record = {"cpu": cpu_model(), "platform": f"{platform.system()} {platform.machine()}", "isa": None,
              "threads": None, "gpu": None,
              "env": {k: os.environ[k] for k in ROUNDING_ENV if os.environ.get(k)}}
    try:
        import torch
    except ImportError:
        return record
    try:
        record["isa"] = str(torch.backends.cpu.get_cpu_capability())
    except (AttributeError, RuntimeError):
        pass
    record["threads"] = int(torch.get_num_threads())
    if torch.cuda.is_available():
        record["gpu"] = torch.cuda.get_device_name(0)
    return record


def machine_label(record: dict | None) -> str:
    """One line for tables: "Intel(R) Xeon(R) Processor, AVX512, 2 threads" (+ GPU, + switches that were set)."""
    if not record:
        return "not recorded"
    parts = [str(record.get("cpu") or "unknown CPU")]
    if record.get("isa"):
        parts.append(str(record["isa"]))
    if record.get("threads"):
        parts.append(f"{record['threads']} threads")
    if record.get("gpu"):
        parts.append(str(record["gpu"]))
    parts += [f"{k}={v}" for k, v in sorted((record.get("env") or {}).items())]
    return ", ".join(parts)
