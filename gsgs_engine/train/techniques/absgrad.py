"""Densification by absolute screen-space gradients (AbsGS) as a training technique.

3DGS clones or splits a Gaussian when the average over views of |sum over its pixels of dL_p/dmeans2d| passes
a threshold. For a large Gaussian over detailed content the pixels pull its centre in opposite directions, the
sum cancels, and it stays large and blurry however wrong it is (AbsGS's "gradient collision"). AbsGS sums the
pixels' gradients' absolute values per axis instead, (sum_p |dL_p/dmx|, sum_p |dL_p/dmy|), so such a Gaussian
is split too. The rasteriser computes that sum in its backward (`render(..., absgrad=True)`: the compiled CPU
kernel, or gsplat's own on CUDA); the trainer accumulates it in place of the plain gradient for every render
that feeds densification.

The absolute sum is never below the plain one, so the threshold rises with it: `threshold` x 3DGS's 0.0002
(gsplat recommends 0.0008, i.e. 4, for its `absgrad` strategy). Installed before the Gaussian count control,
which lowers the threshold from this raised base when a model is far below its budget. Where only the pure-torch
reference rasteriser runs (no compiler), which cannot give per-pixel gradients cheaply, the technique leaves the
plain statistic and threshold in place and says so in the log and its report.
"""

from __future__ import annotations

from gsgs_engine import GsgsError
from gsgs_engine.train.technique import Technique

DEFAULT_THRESHOLD = 4.0  # x the plain-gradient threshold; gsplat's grow_grad2d 0.0008 for absgrad


class AbsoluteGradients(Technique):
    name = "absgrad"

    def __init__(self, threshold: float = DEFAULT_THRESHOLD):
        if not float(threshold) > 0:
            raise GsgsError(f"absgrad: threshold is a positive multiple of the gradient threshold (got {threshold})")
        self.threshold = float(threshold)
        self.base_threshold: float | None = None
        self.unavailable: str | None = None  # why the plain statistic is used instead (set at install)

    def install(self, trainer) -> None:
        import torch

        from gsgs_engine.render.api import select_backend

        dc = trainer.config.densify_config
        if self.base_threshold is None:  # once: a second install (resume) must not raise it again
            self.base_threshold = float(dc.grad_threshold)
        backend = select_backend(trainer.config.backend, trainer.device, torch.float32)
        self.unavailable = None
        if backend == "reference":  # no compiled rasteriser here: train as without this technique, and say so
            self.unavailable = ("the pure-torch reference rasteriser (asked for, or no compiled one: `python -m "
                                "gsgs_engine build-ext` shows why) does not compute it; densified by the plain gradient")
            trainer.log(f"absgrad: {self.unavailable}")
            return
        dc.grad_threshold = self.base_threshold * self.threshold
        dc.gradient = "abs"

    def report(self) -> dict:
        if self.unavailable:
            return {"statistic": "off: " + self.unavailable, "threshold_scale": self.threshold,
                    "base_grad_threshold": self.base_threshold, "grad_threshold": self.base_threshold}
        return {"statistic": "sum over pixels of |dL_p/dmeans2d| per axis (AbsGS), in place of |sum dL_p/dmeans2d|",
                "threshold_scale": self.threshold, "base_grad_threshold": self.base_threshold,
                "grad_threshold": None if self.base_threshold is None else self.base_threshold * self.threshold}
