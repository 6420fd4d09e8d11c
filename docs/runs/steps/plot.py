"""The accuracy-vs-steps plot of docs/speed.md (run from the repository root): the cells' figures as measured there."""
import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt
# (steps, PSNR, LPIPS) of `--prior auto`, seed 0: docs/speed.md "Accuracy against steps"
cells = {"blender_lego (8 views)": [(1000, 24.30, 0.121), (3000, 25.50, 0.095)],
         "llff_flower (3 views)": [(1000, 20.87, 0.309), (3000, 21.16, 0.273)]}
fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.6))
for name, pts in cells.items():
    a.plot([p[0] for p in pts], [p[1] for p in pts], "o-", label=name)
    b.plot([p[0] for p in pts], [p[2] for p in pts], "o-", label=name)
a.set_xlabel("training steps"); a.set_ylabel("test PSNR (dB)"); a.set_xticks([1000, 3000]); a.grid(alpha=0.3)
b.set_xlabel("training steps"); b.set_ylabel("test LPIPS (VGG), lower is better"); b.set_xticks([1000, 3000]); b.grid(alpha=0.3)
a.legend(fontsize=8)
fig.suptitle("--prior auto, seed 0, 2-core CPU: what 3x the steps buys")
fig.tight_layout(); fig.savefig("docs/accuracy_steps.png", dpi=100)
