"""The accuracy-against-steps plot of docs/speed.md (run from the repository root): `--prior auto` as it runs today
(session 42's recipes), read from the protocol cells' metrics files; seeds 0-2, the mean over seeds with their spread
as error bars, each point annotated with the median training seconds of its cells (2-core CPU, AMD EPYC with AVX-512,
two threads, one cell at a time; cells beside a CI run excluded from the seconds).

  300 steps (the `fast` preset): docs/runs/screens_2026-12-05s42/*_auto300_seed*.json (session 42)
  1000 steps (`balanced`): orbits docs/runs/screens_2026-12-05s38/*_pd005_seed*.json (session 38: the recipe with
      the clone / split boundary), forward-facing docs/runs/screens_2026-12-05s40/*_planned_seed*.json (session 40)
  3000 steps (`best`): orbits docs/runs/screens_2026-12-05s39/*_L3kcs_seed*.json (session 39), forward-facing
      docs/runs/screens_2026-12-05s41/*_L3kab_seed*.json (sessions 41-42: absolute gradients)
  10000 steps: session 10's recipe, seed 0 only (docs/runs/steps/*_auto_10000_seed0.metrics.json), hollow markers:
      an older recipe, not comparable with the lines, kept as the only 10000-step cells there are.
"""
import json
import statistics
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

RUNS = Path("docs/runs")
SCENES = {"blender_lego (8 views)": ("blender", "lego"), "blender_chair (8 views)": ("blender", "chair"),
          "llff_flower (3 views)": ("llff", "flower"), "llff_horns (3 views)": ("llff", "horns")}
# steps -> protocol -> (folder, tag)
CELLS = {300: {"blender": ("screens_2026-12-05s42", "auto300"), "llff": ("screens_2026-12-05s42", "auto300")},
         1000: {"blender": ("screens_2026-12-05s38", "pd005"), "llff": ("screens_2026-12-05s40", "planned")},
         3000: {"blender": ("screens_2026-12-05s39", "L3kcs"), "llff": ("screens_2026-12-05s41", "L3kab")}}
SEEDS = (0, 1, 2)
BESIDE_CI = {("llff", "flower", 3000, 1), ("llff", "horns", 3000, 1)}  # session 41's seed 1: seconds not comparable
OLD_10000 = {"blender_lego (8 views)": RUNS / "steps/blender_lego_auto_10000_seed0.metrics.json",
             "llff_flower (3 views)": RUNS / "steps/llff_flower_auto_10000_seed0.metrics.json"}


def cell(protocol, scene, steps, seed):
    folder, tag = CELLS[steps][protocol]
    return json.loads((RUNS / folder / f"{protocol}_{protocol}_{scene}_{tag}_seed{seed}.json").read_text())


def table():
    """name -> steps -> (PSNR mean, sd, LPIPS mean, sd, median train seconds)"""
    out = {}
    for name, (protocol, scene) in SCENES.items():
        for steps in CELLS:
            got = [cell(protocol, scene, steps, k) for k in SEEDS]
            assert all(m["iterations"] == steps for m in got), (name, steps)
            psnr, lpips = [m["psnr"] for m in got], [m["lpips"] for m in got]
            secs = [m["train_seconds"] for k, m in zip(SEEDS, got) if (protocol, scene, steps, k) not in BESIDE_CI]
            out.setdefault(name, {})[steps] = (statistics.mean(psnr), statistics.stdev(psnr), statistics.mean(lpips),
                                               statistics.stdev(lpips), statistics.median(secs))
    return out


if __name__ == "__main__":
    rows = table()
    print("| scene | steps | PSNR (seeds 0-2) | LPIPS (VGG) | median train s a cell |\n|---|---|---|---|---|")
    for name, by_steps in rows.items():
        for steps, (p, psd, lp, lsd, sec) in by_steps.items():
            print(f"| {name} | {steps} | {p:.2f} ± {psd:.2f} | {lp:.3f} | {sec:.0f} |")
    for protocol in ("blender", "llff"):
        for steps in CELLS:
            names = [n for n, (p, _) in SCENES.items() if p == protocol]
            per_seed = [statistics.mean(cell(protocol, SCENES[n][1], steps, k)["psnr"] for n in names) for k in SEEDS]
            print(f"{protocol} {steps} steps: {statistics.mean(per_seed):.2f} ± {statistics.stdev(per_seed):.2f} dB")
    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 4.2))
    for i, (name, by_steps) in enumerate(rows.items()):
        steps = sorted(by_steps)
        colour = f"C{i}"
        a.errorbar(steps, [by_steps[s][0] for s in steps], yerr=[by_steps[s][1] for s in steps], fmt="o-",
                   capsize=3, color=colour, label=name)
        b.errorbar(steps, [by_steps[s][2] for s in steps], yerr=[by_steps[s][3] for s in steps], fmt="o-",
                   capsize=3, color=colour, label=name)
        for s in steps:  # of the two LLFF lines, the upper one's seconds above its points, the others' below
            above = ("flower" in name) == (s != 300)
            a.annotate(f"{by_steps[s][4]:.0f} s", (s, by_steps[s][0]), textcoords="offset points",
                       xytext=(4, 5 if above and "llff" in name else -11), fontsize=7, color=colour)
        if name in OLD_10000:
            old = json.loads(OLD_10000[name].read_text())
            a.plot([10000], [old["psnr"]], "o", mfc="none", color=colour)
            b.plot([10000], [old["lpips"]], "o", mfc="none", color=colour)
    for axis in (a, b):
        axis.set_xscale("log")
        axis.set_xticks([300, 1000, 3000, 10000], ["300\nfast", "1000\nbalanced", "3000\nbest", "10000"])
        axis.minorticks_off()
        axis.grid(alpha=0.3)
        axis.set_xlabel("training steps")
    a.set_ylabel("test PSNR (dB)")
    a.margins(y=0.1)
    b.set_ylabel("test LPIPS (VGG), lower is better")
    handles, labels = a.get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8)
    fig.suptitle("--prior auto today, 2-core CPU (seeds 0-2; hollow: 10000 steps, an older recipe, seed 0)", fontsize=10)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    fig.savefig("docs/accuracy_steps.png", dpi=100)
