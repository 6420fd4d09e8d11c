"""The accuracy-vs-steps plot of docs/speed.md (run from the repository root): the cells' figures as measured there.

`--prior auto`, the recipe of this build (the orbit recipe's binocular view every second step, density-guided dropout on LLFF); NeRF-synthetic:
mean over seeds 0-2 with the seeds' spread as error bars (1000 steps: docs/speed.md's 3-seed bino2 grid, docs/runs/screens_2026-11-26/; 3000
steps: the *_3000_seed*.metrics.json beside this file); LLFF: seeds 0-2 too (1000 steps: docs/runs/screens_2026-11-26/
llff_{flower,horns}_ddrop_seed*; 3000 steps: llff_{flower,horns}_auto_3000_seed* here); lego and flower at 10000
steps: seed 0 ({blender_lego,llff_flower}_auto_10000_seed0 here).
"""
import statistics

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

# name -> {steps: ([PSNR per seed], [LPIPS per seed])}
CELLS = {
    "blender_lego (8 views)": {1000: ([24.33, 24.62, 24.30], [0.120, 0.119, 0.121]),
                               3000: ([25.30, 25.39, 25.52], [0.096, 0.095, 0.095]),
                               10000: ([25.37], [0.095])},  # seed 0 only
    "blender_chair (8 views)": {1000: ([27.82, 27.56, 28.09], [0.073, 0.074, 0.072]),
                                3000: ([28.54, 28.59, 28.60], [0.057, 0.057, 0.055])},
    "llff_flower (3 views)": {1000: ([20.90, 20.94, 21.17], [0.301, 0.300, 0.304]),
                              3000: ([21.01, 21.05, 21.02], [0.268, 0.266, 0.268]),
                              10000: ([20.89], [0.260])},  # seed 0 only
    "llff_horns (3 views)": {1000: ([20.36, 20.17, 20.35], [0.321, 0.319, 0.316]),
                             3000: ([20.52, 20.72, 20.87], [0.267, 0.268, 0.264])},
}


def mean_sd(values):
    return statistics.mean(values), (statistics.stdev(values) if len(values) > 1 else 0.0)


fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.6))
for name, by_steps in CELLS.items():
    steps = sorted(by_steps)
    for axis, k in ((a, 0), (b, 1)):
        stats = [mean_sd(by_steps[s][k]) for s in steps]
        axis.errorbar(steps, [m for m, _ in stats], yerr=[sd for _, sd in stats], fmt="o-", capsize=3, label=name)
for axis in (a, b):
    axis.set_xscale("log")
    axis.set_xticks([1000, 3000, 10000], ["1000", "3000", "10000"])
    axis.minorticks_off()
a.set_xlabel("training steps"); a.set_ylabel("test PSNR (dB)"); a.grid(alpha=0.3)
b.set_xlabel("training steps"); b.set_ylabel("test LPIPS (VGG), lower is better")
b.grid(alpha=0.3)
a.legend(fontsize=8)
# measured training seconds on the 2-core machine, two threads (docs/speed.md: the estimate's reference cells of
# session 10, the quiet 3000-step LLFF cells of session 9, the 10000-step lego cell of session 10; the 10000-step
# flower cell of session 11 ran beside other cells and is not annotated)
SECONDS = {("blender_lego (8 views)", 1000): 78, ("blender_lego (8 views)", 10000): 1036,
           ("llff_flower (3 views)", 1000): 188, ("llff_flower (3 views)", 3000): 570,
           ("llff_horns (3 views)", 3000): 580}
for (name, steps), sec in SECONDS.items():
    psnr = mean_sd(CELLS[name][steps][0])[0]
    a.annotate(f"{sec} s", (steps, psnr), textcoords="offset points", xytext=(-34 if steps == 10000 else 4, -11),
               fontsize=7)
fig.suptitle("--prior auto, 2-core CPU: what longer schedules buy (seeds 0-2; 10000 steps: seed 0)")
fig.tight_layout(); fig.savefig("docs/accuracy_steps.png", dpi=100)
