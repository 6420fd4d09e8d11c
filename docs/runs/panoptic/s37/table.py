"""Issue 31 on other time windows of the capture, every model, today's recipe (texture rate 0.01): frames 0-9
(session 36's grid), 10-19 (session 36, `--first-frame 10`) and 20-29 (session 37, `--first-frame 20`, seeds 0-2), the same
command (docs/runs/panoptic/s36/screen.py with FIRST_FRAME; w20_cC_sS.json: ...:w20:C:S:4d,static_all,static_per_frame:
1000:300, w20pf100_cC_sS.json: the per-frame models at 100 steps a frame). `python docs/runs/panoptic/s37/table.py`."""
import importlib.util
from pathlib import Path

HERE = Path(__file__).resolve().parent
S36 = HERE.parent / "s36"
_spec = importlib.util.spec_from_file_location("table_s35", HERE.parent / "s35" / "table.py")
table_s35 = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(table_s35)

table_s35.print_table("frames 20-29 (session 37), seeds 0-2", "w20", HERE, lambda c, s: f"w20pf100_c{c}_s{s}.json")
table_s35.print_table("frames 10-19 (session 36), seed 0", "w10", S36, lambda c, s: f"w10pf100_c{c}_s{s}.json")

# The per-frame models of 3 cameras again with the fallback in proportion (init.mvs.fallback_count; w20fb_c3_sS.json,
# w20fbpf100_c3_sS.json: ...:w20fb:3:S:static_per_frame:1000:300 and ...:w20fbpf100:3:S:static_per_frame:1000:100);
# the 4D and all-frames models do not reach the fallback, so theirs are the runs above.
import json
import tempfile

with tempfile.TemporaryDirectory() as tmp:
    for seed in (0, 1, 2):
        merged = json.loads((HERE / f"w20_c3_s{seed}.json").read_text())
        merged["static_per_frame"] = json.loads((HERE / f"w20fb_c3_s{seed}.json").read_text())["static_per_frame"]
        (Path(tmp) / f"w20m_c3_s{seed}.json").write_text(json.dumps(merged))
        (Path(tmp) / f"w20mpf100_c3_s{seed}.json").write_bytes((HERE / f"w20fbpf100_c3_s{seed}.json").read_bytes())
    table_s35.print_table("frames 20-29, 3 cameras, the per-frame models with the fallback in proportion (session 37)",
                          "w20m", Path(tmp), lambda c, s: f"w20mpf100_c{c}_s{s}.json")
