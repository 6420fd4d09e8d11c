"""Means over seeds of oracle.jsonl (docs/runs/panoptic/s38/oracle.py's output): one row per cameras x window."""
import json
from collections import defaultdict
from pathlib import Path

import numpy as np

rows = [json.loads(line) for line in (Path(__file__).parent / "oracle.jsonl").read_text().splitlines()]
groups = defaultdict(list)
for r in rows:
    groups[(r["first_frame"], r["cams"])].append(r["mean"])
print("| frames | cameras | seeds | lead | static room + perfect region: lead | 4D room + perfect region: lead "
      "| static room + 4D region: lead | 4D room + static region: lead | outside the region: 4D - static |")
print("|---|---|---|---|---|---|---|---|---|")
for (first, cams), ms in sorted(groups.items()):
    def d(key):
        return float(np.mean([m[key] - m["static"] for m in ms]))
    room = float(np.mean([m["4d_room_psnr"] - m["static_room_psnr"] for m in ms]))
    print(f"| {first}-{first + 9} | {cams} | {len(ms)} | {d('4d'):+.2f} | {d('static_room_perfect_people'):+.2f} "
          f"| {d('4d_room_perfect_people'):+.2f} | {d('static_room_4d_people'):+.2f} | {d('4d_room_static_people'):+.2f} "
          f"| {room:+.2f} |")
