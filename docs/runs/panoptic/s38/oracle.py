"""Where a 4D lead over the best static model can come from: the people or the room (issue 31, session 38).

Reads the test-view renders `gsgs bench dynamic` wrote (every test view of a 4D model and of a static baseline; the
runs of docs/runs/panoptic/s36/screen.py, kept under /tmp/s36/pan) and splits each view's error by the bench's
"dynamic region" (bench.dynamic_region: the capture has foreground masks for its training cameras only, so on the
test cameras it is the pixels that change over time, i.e. the moving people):
  - the scores as the bench computed them (a check: the mean over views of PSNR, from the 8-bit renders);
  - the share of pixels the people cover and of the squared error they carry, per model;
  - oracles: each model with its dynamic-region pixels replaced by the photo's (what a perfect model of the people would
    score on that model's room), and the swaps (the static model's room with the 4D model's people, and back).
The lead a perfect model of the people can give over the best static model is
  mean PSNR(static room + the photo's people) - mean PSNR(static),
so where that is below the 1.0 dB issue 31 asks for, the rest must come from a better room.

usage: python docs/runs/panoptic/s38/oracle.py CAMS FIRST_FRAME RUN_4D RUN_STATIC [STATIC_MODEL] [...more quadruples]
  RUN_4D: a bench output folder holding renders/4d; RUN_STATIC: one holding renders/STATIC_MODEL
  (static_per_frame: renders/static_per_frame/t*/; static_all: renders/static_all/).
  Prints one table row per pair; --json FILE also writes one JSON line per pair to FILE.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

DATA = Path("/work/shared/data/panoptic_basketball")


def _renders(folder: Path) -> dict[str, Path]:
    """name -> png over a renders folder (and its t*/ subfolders): files are NNN_<view name>.png."""
    out = {}
    for p in sorted(folder.rglob("*.png")):
        out[p.stem.split("_", 1)[1]] = p
    return out


def _read(path: Path) -> np.ndarray:
    from gsgs_engine.io.images import decode_image

    return np.asarray(decode_image(path), dtype=np.float64)[..., :3]


def _psnr(mse: float) -> float:
    return float(-10.0 * np.log10(max(mse, 1e-12)))


def analyse(cams: int, first_frame: int, run_4d: Path, run_static: Path, static_model: str) -> dict:
    from gsgs_engine.bench.dynamic import load_bench_scene
    from gsgs_engine.bench.dynamic_region import region_masks
    from gsgs_engine.train.evaluate import _safe_name as safe_name

    scene = load_bench_scene(DATA, cams, 10, 0.5, first_frame)
    r4 = _renders(run_4d / "renders" / "4d")
    rs = _renders(run_static / "renders" / static_model)
    region_fn, region_what = region_masks(scene.test)
    rows = []
    for view in scene.test:
        key = safe_name(view.name)
        if key not in r4 or key not in rs:
            raise SystemExit(f"no render of test view {view.name} in {run_4d} or {run_static}")
        gt = np.asarray(view.image(), dtype=np.float64)[..., :3]
        mask = region_fn(view)
        if mask is None:
            raise SystemExit(f"{view.name}: no dynamic region to split the error by")
        a, s = _read(r4[key]), _read(rs[key])
        m3 = np.repeat(mask[..., None], 3, axis=-1)
        n = gt.size

        def parts(img):
            err = (img - gt) ** 2
            return float(err[m3].sum()), float(err[~m3].sum())

        a_fg, a_bg = parts(a)
        s_fg, s_bg = parts(s)
        rows.append({
            "name": view.name, "people_share": float(mask.mean()),
            "4d": _psnr((a_fg + a_bg) / n), "static": _psnr((s_fg + s_bg) / n),
            "4d_people_share_of_error": a_fg / max(a_fg + a_bg, 1e-12),
            "static_people_share_of_error": s_fg / max(s_fg + s_bg, 1e-12),
            "4d_room_perfect_people": _psnr(a_bg / n), "static_room_perfect_people": _psnr(s_bg / n),
            "static_room_4d_people": _psnr((s_bg + a_fg) / n), "4d_room_static_people": _psnr((a_bg + s_fg) / n),
            "4d_room_psnr": _psnr(a_bg / max(n - m3.sum(), 1)), "static_room_psnr": _psnr(s_bg / max(n - m3.sum(), 1)),
        })
    keys = [k for k in rows[0] if k != "name"]
    mean = {k: float(np.mean([r[k] for r in rows])) for k in keys}
    stored = {}
    for label, run, model in (("4d", run_4d, "4d"), ("static", run_static, static_model)):
        res = json.loads((run / "results.json").read_text())
        stored[label] = res[model]["psnr"]
    return {"region": region_what, "cams": cams, "first_frame": first_frame, "run_4d": str(run_4d), "run_static": str(run_static),
            "static_model": static_model, "views": len(rows), "mean": mean, "stored_psnr": stored}


def main(argv: list[str]) -> int:
    json_out = None
    if "--json" in argv:
        i = argv.index("--json")
        json_out = Path(argv[i + 1])
        argv = argv[:i] + argv[i + 2:]
    results = []
    i = 0
    while i < len(argv):
        cams, first, run_4d, run_static = int(argv[i]), int(argv[i + 1]), Path(argv[i + 2]), Path(argv[i + 3])
        model = "static_per_frame"
        i += 4
        if i < len(argv) and argv[i].startswith("static_"):
            model = argv[i]
            i += 1
        results.append(analyse(cams, first, run_4d, run_static, model))
    head = ("| cameras, frames | 4D / static (the bench's) | lead | people: pixels, share of the 4D / static error "
            "| static room + perfect people: lead | 4D room + perfect people: lead | static room + 4D people: lead "
            "| 4D room + static people: lead | room PSNR 4D / static |")
    print(head)
    print("|" + "---|" * head.count(" | ") + "---|")
    for r in results:
        m, st = r["mean"], r["stored_psnr"]
        base = m["static"]
        print(f"| {r['cams']}, {r['first_frame']}-{r['first_frame'] + 9} | {m['4d']:.2f} / {base:.2f} "
              f"({st['4d']:.2f} / {st['static']:.2f}) | {m['4d'] - base:+.2f} | {100 * m['people_share']:.1f} %, "
              f"{100 * m['4d_people_share_of_error']:.0f} / {100 * m['static_people_share_of_error']:.0f} % "
              f"| {m['static_room_perfect_people'] - base:+.2f} | {m['4d_room_perfect_people'] - base:+.2f} "
              f"| {m['static_room_4d_people'] - base:+.2f} | {m['4d_room_static_people'] - base:+.2f} "
              f"| {m['4d_room_psnr']:.2f} / {m['static_room_psnr']:.2f} |")
    if json_out is not None:
        json_out.write_text("".join(json.dumps(r) + "\n" for r in results))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
