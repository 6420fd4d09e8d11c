"""Issue 31 with the background sphere's texture at learning rate 0.01 (session 36) against 0.05 (session 35): every
model, seeds 0-2. `python docs/runs/panoptic/s36/table.py` (from the repository root) prints the tables from the results
kept beside it and in ../s35 (sph01_cC_sS.json: screen.py ...:sph01:C:S:4d,static_all,static_per_frame:1000:300;
pf100sph01_cC_sS.json: the per-frame models at 100 steps a frame, the 4D model's step total)."""
import importlib.util
from pathlib import Path

HERE = Path(__file__).resolve().parent
S35 = HERE.parent / "s35"
_spec = importlib.util.spec_from_file_location("table_s35", S35 / "table.py")
table_s35 = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(table_s35)  # its helpers; its own tables print only when run itself

table_s35.print_table("the sphere, texture learning rate 0.01 (session 36)", "sph01", HERE,
                      lambda c, s: f"pf100sph01_c{c}_s{s}.json")
table_s35.print_table("the sphere, texture learning rate 0.05 (session 35)", "sph", S35,
                      lambda c, s: f"pf100sph_c{c}_s{s}.json")
