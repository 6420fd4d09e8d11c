"""Which machine a run came from (gsgs_engine.machine): recorded in metrics.json and in `gsgs bench sparse`."""

from __future__ import annotations

import json

import torch

from gsgs_engine.bench.sparse import machines_note
from gsgs_engine.machine import cpu_model, machine_label, machine_record


def test_record_names_the_processor_and_torch_dispatch(monkeypatch):
    monkeypatch.delenv("MKL_CBWR", raising=False)
    monkeypatch.delenv("GSGS_TILE_VARIANT", raising=False)
    record = machine_record()
    assert json.loads(json.dumps(record)) == record  # JSON-ready
    assert record["cpu"] == cpu_model() and record["cpu"].strip()
    assert record["isa"] == str(torch.backends.cpu.get_cpu_capability())
    assert record["threads"] == torch.get_num_threads()
    assert record["env"] == {} or set(record["env"]) <= {"MKL_ENABLE_INSTRUCTIONS", "ATEN_CPU_CAPABILITY",
                                                         "ONEDNN_MAX_CPU_ISA", "GSGS_NO_FMA"}
    # a switch that changes the roundings is part of the record, and of the label
    monkeypatch.setenv("MKL_CBWR", "AVX2")
    switched = machine_record()
    assert switched["env"]["MKL_CBWR"] == "AVX2" and "MKL_CBWR=AVX2" in machine_label(switched)


def test_label():
    record = {"cpu": "Some CPU", "isa": "AVX2", "threads": 2, "gpu": None, "env": {}}
    assert machine_label(record) == "Some CPU, AVX2, 2 threads"
    assert machine_label({**record, "gpu": "A GPU", "env": {"GSGS_TILE_VARIANT": "fma"}}) == \
        "Some CPU, AVX2, 2 threads, A GPU, GSGS_TILE_VARIANT=fma"
    assert machine_label(None) == "not recorded"  # a metrics.json of an older build


def test_bench_table_warns_when_cells_came_from_two_machines():
    assert machines_note([]) == []
    assert machines_note(["Some CPU, AVX2, 2 threads"]) == ["Cells trained on: Some CPU, AVX2, 2 threads."]
    (warning,) = machines_note(["Some CPU, AVX2, 2 threads", "Other CPU, AVX512, 2 threads"])
    assert "2 machines" in warning and "Other CPU" in warning and "compare cells of one machine" in warning
