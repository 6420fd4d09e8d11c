"""The GS-GS prior loop (Alg. 1) as a training technique: rounds of render -> adapt -> generate.

After a warm-up, each round renders every training and pseudo view, adapts the generator
(diffusion + LoRA with the geometry-aware loss, eq. 4, 6) or warps the training photos
(the weights-free warp-inpaint generator), and hands the new pseudo images to the
pseudo-view technique (eq. 11's pseudo terms); with a depth source it also installs the depth
regulariser (eq. 10) and gives it estimates of the new targets. Every round's pseudo images and
depths go to OUT/pseudo/round_k/ (the "dataset evolution").
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import torch

from gsgs_engine.priors.config import PriorConfig
from gsgs_engine.train.technique import Technique
from gsgs_engine.train.techniques.depth_regulariser import DepthRegulariser
from gsgs_engine.train.techniques.pseudo_views import PseudoSupervision, PseudoView


def round_steps(iters: int, warmup_fraction: float, rounds: int) -> list[int]:
    """Steps after which round k (0-based) regenerates the pseudo views."""
    if rounds <= 0:
        return []
    start = max(1, int(round(iters * warmup_fraction)))
    span = max(iters - start, 1)
    return sorted({min(iters - 1, start + (k * span) // rounds) for k in range(rounds)} - {0})


def recovered_round_steps(steps: list[int], schedule) -> list[int]:
    """Move each round off the steps just after an opacity reset.

    Right after a reset every Gaussian is nearly transparent: pseudo renders then cover
    nothing, the warp has no surface to carry the photos, and the pseudo targets would teach
    the model to stay empty (measured on lego_200: a round 15 steps after a reset took the
    test PSNR from 18.3 to 9.9 dB). A round waits until 3/4 of a reset period has passed.
    """
    every = schedule.opacity_reset_every
    recover = max(1, (3 * every) // 4)
    out = []
    for s in steps:
        while s < schedule.iters - 1:
            last_reset = min(s, schedule.densify_until) // every * every
            if last_reset == 0 or s - last_reset >= recover:
                break
            s += 1
        out.append(s)
    return sorted(set(out))


def _to_u8(img: torch.Tensor) -> np.ndarray:
    return (img.detach().cpu().numpy().clip(0, 1) * 255 + 0.5).astype(np.uint8)


def _save_png(path: Path, rgb_or_gray: np.ndarray) -> None:
    import cv2

    path.parent.mkdir(parents=True, exist_ok=True)
    arr = rgb_or_gray[..., ::-1] if rgb_or_gray.ndim == 3 else rgb_or_gray
    cv2.imwrite(str(path), np.ascontiguousarray(arr))


def _depth_png(inv: torch.Tensor, mask: torch.Tensor | None = None) -> np.ndarray:
    d = inv.detach().float()
    valid = torch.isfinite(d) & (d > 0) if mask is None else mask.bool()
    if valid.any():
        lo, hi = d[valid].min(), d[valid].max()
        d = torch.where(valid, (d - lo) / (hi - lo).clamp_min(1e-9), torch.zeros_like(d))
    return _to_u8(d)


def _same_moment(photos, camera):
    """For a dynamic scene only photos taken at the pseudo view's time can be warped into it."""
    if camera.time is None:
        return photos
    same = [ph for ph in photos if ph.camera.time is not None and abs(ph.camera.time - camera.time) < 1e-6]
    return same or photos


def orbit_focus(cameras) -> np.ndarray | None:
    """The point orbiting cameras look at (their optical axes cross), else None (forward-facing:
    pseudo centres then interpolate on straight lines, which stay between the cameras anyway)."""
    from gsgs_engine.cameras import focus_point

    if len(cameras) < 2:
        return None
    focus, how = focus_point(cameras)
    return focus if how == "optical axes intersection" else None


SEED_STRIDE = 4  # grid of seeded Gaussians, in pixels at SEED_REFERENCE_SIZE
SEED_REFERENCE_SIZE = 512  # long image side at which the grid is SEED_STRIDE pixels
SEED_ROUND_MIN = 20_000  # a round may always seed this many, and otherwise at most the model's own size


def seed_stride(camera, stride: int = SEED_STRIDE) -> int:
    """Grid spacing in pixels for seeding: `stride` up to SEED_REFERENCE_SIZE px, proportionally coarser above,
    so a view contributes at most about (SEED_REFERENCE_SIZE / stride)^2 seeds whatever its resolution."""
    long_side = max(camera.width, camera.height)
    return max(int(stride), int(round(stride * long_side / SEED_REFERENCE_SIZE)))


class PriorLoop(Technique):
    """Alg. 1's rounds; installs the pseudo-view technique and, with a depth source, the depth regulariser."""

    name = "gsgs_prior"

    def __init__(self, cfg: PriorConfig, plan: dict, out_dir: Path, log=print):
        self.cfg = cfg
        self.plan = plan
        self.out_dir = Path(out_dir)
        self.log = log
        self.rounds_done = 0
        self.round_stats: list[dict] = []
        self.pseudo_depth: list[tuple[torch.Tensor, torch.Tensor]] = []  # estimates of every pseudo view's target
        self.depth: DepthRegulariser | None = None
        self.estimator = None  # a depth-estimation model, when the depth source is one
        self.supervision: PseudoSupervision | None = None
        self.diffusion = None
        self.pseudo = []
        self.active: list[int] = []  # indices into self.pseudo of the views supervised this round

    # -- set-up -----------------------------------------------------------------------
    def install(self, trainer) -> None:
        from gsgs_engine.priors.poses import (authored_pseudo_views, interpolated_pseudo_views,
                                              surrounding_pseudo_views)

        self.trainer = trainer
        cams = [v.camera for v in trainer.train_views]
        self.steps = recovered_round_steps(
            round_steps(trainer.config.iters, self.cfg.warmup_fraction, self.plan.get("rounds", 0)), trainer.schedule)
        if self.plan["generator"] and trainer.scene.has_time:
            # 4D: pseudo poses at sampled times, each tied to a training photo of the same moment
            from gsgs_engine.train.dynamic import spacetime_pseudo_views, views_by_frame

            per_time = max(1, self.cfg.num_pseudo // max(len(views_by_frame(trainer.train_views)), 1))
            self.pseudo = spacetime_pseudo_views(trainer.train_views, per_time, jitter=self.cfg.jitter,
                                                 seed=trainer.config.seed)
        elif self.plan["generator"]:
            focus = orbit_focus(cams)
            # forward-facing rigs: `ring_fraction` of the views (default all) on a ring past the rig's edges, the
            # rest between neighbouring cameras. (Orbits: all between neighbours; views placed in an orbit's widest
            # gaps measured worse on lego_200, 21.65 vs 22.02 dB: warps across those gaps are too far off.)
            ring = (int(self.cfg.num_pseudo * self.cfg.ring_fraction + 1e-9) if (focus is None and self.cfg.reach > 0)
                    else 0)
            self.pseudo = interpolated_pseudo_views(cams, self.cfg.num_pseudo - ring, self.cfg.jitter,
                                                    trainer.config.seed, focus=focus)
            self.pseudo += surrounding_pseudo_views(cams, ring, self.cfg.reach, first_index=len(self.pseudo))
            self.pseudo += authored_pseudo_views(self.plan.get("authored_poses", []), cams)
        # Scenes without a real background (photos): what a pseudo view shows empty is unseen content,
        # to be filled (inpainted, and new Gaussians placed there); with one (RGBA), empty is background.
        # (4D models carry per-Gaussian motion that seeding does not set up: static scenes only;
        # the filling is the warp-inpaint generator's.)
        self.fill_empty = (self.plan["generator"] == "warp-inpaint" and not trainer.scene.has_alpha
                           and not trainer.scene.has_time)
        self.plan["fill_empty"] = self.fill_empty
        t0 = time.perf_counter()
        self.supervision = trainer.add_technique(PseudoSupervision(every=self.cfg.pseudo_every,
                                                                       scale=self.cfg.pseudo_scale))
        if self.plan.get("depth_source"):
            self.depth = trainer.add_technique(DepthRegulariser(
                self.plan["depth_source"], self.cfg.lambda_reg, self.plan,
                sparse_points=self.plan.pop("_sparse_points", None), log=self.log))
            self.estimator = self.depth.estimator  # the diffusion generator conditions on it too
            if not self.depth.enabled:
                self.depth = None
        if self.plan["generator"] == "diffusion":
            from gsgs_engine.priors.diffusion import DiffusionPrior, DiffusionSettings

            settings = DiffusionSettings(model_dir=self.cfg.diffusion_model, adapter_dir=self.cfg.depth_adapter,
                                         device=self.cfg.device, seed=trainer.config.seed, **self.cfg.diffusion)
            self.diffusion = DiffusionPrior(settings)
            self.plan["diffusion"] = settings.to_dict()
        trainer.phase_seconds["prior_setup"] = time.perf_counter() - t0
        trainer.phase_seconds.setdefault("prior_render", 0.0)
        trainer.phase_seconds.setdefault("prior_adapt", 0.0)
        trainer.phase_seconds.setdefault("prior_generate", 0.0)
        self.plan["round_steps"] = self.steps
        # A resumed run past the warm-up regenerates the current round from the restored model.
        if self.pseudo and self.steps and trainer.step >= self.steps[0]:
            self.rounds_done = sum(1 for s in self.steps if s <= trainer.step) - 1
            self.run_round()

    def report(self) -> dict:
        return {"generator": self.plan.get("generator"), "pseudo_views": len(self.pseudo),
                "round_steps": list(getattr(self, "steps", [])), "rounds_done": self.rounds_done}

    # -- Alg. 1 rounds ----------------------------------------------------------------------
    def after_step(self, trainer, step: int) -> None:
        if self.pseudo and self.rounds_done < len(self.steps) and step >= self.steps[self.rounds_done]:
            self.run_round()

    @torch.no_grad()
    def _render_all(self):
        from gsgs_engine.priors.warp_inpaint import TrainingPhoto, surface_depth

        tr = self.trainer
        photos = []
        for i, v in enumerate(tr.train_views):
            out = tr.render(v.camera)
            photos.append(TrainingPhoto(v.camera, tr._targets[i], surface_depth(out.depth, out.alpha)))
        renders = [tr.render(p.camera) for p in self.pseudo]
        return photos, renders

    def run_round(self) -> None:
        tr, k = self.trainer, self.rounds_done
        t0 = time.perf_counter()
        photos, renders = self._render_all()
        t1 = time.perf_counter()
        tr.phase_seconds["prior_render"] += t1 - t0
        stats: dict = {"round": k, "step": tr.step, "generator": self.plan["generator"]}
        if self.plan["generator"] == "diffusion":
            images = self._diffusion_round(photos, renders, stats)
        else:
            images = self._warp_round(photos, renders, stats)
        t2 = time.perf_counter()
        if self.depth is not None:
            self.pseudo_depth = [self.depth.estimate(p.camera, img) for p, img in zip(self.pseudo, images)]
        # A pseudo view the model barely covers carries no surface to supervise: leave it out this round
        # (right after an opacity reset, say); unless empty is unseen content, which the round fills.
        train_cover = float(np.median([float((ph.depth > 0).float().mean()) for ph in photos]))
        keep = [self.fill_empty or float((out.alpha > 0.5).float().mean()) >= 0.5 * train_cover for out in renders]
        if self.fill_empty:
            stats["gaussians_added_in_empty"] = self._fill_empty_with_gaussians(renders, images)
        stats["pseudo_views_used"] = int(sum(keep))
        stats["pseudo_views_skipped_low_coverage"] = len(keep) - int(sum(keep))
        self.active = [j for j, k in enumerate(keep) if k]
        self.supervision.set_views([PseudoView(camera=self.pseudo[j].camera, image=images[j],
                                               weight=self.pseudo_weight(self.pseudo[j]), name=self.pseudo[j].name,
                                               nearest_train=self.pseudo[j].nearest_train)
                                    for j in self.active])
        if self.depth is not None:
            self.depth.set_pseudo_depth([self.pseudo_depth[j] for j in self.active])
        tr.phase_seconds["prior_generate"] += time.perf_counter() - t2
        self._save_round(k, images, renders, stats)
        self.rounds_done += 1
        self.round_stats.append(stats)
        seeded = stats.get("gaussians_added_in_empty", 0)
        self.log(f"prior round {k + 1}/{len(self.steps)} at step {tr.step}: {len(images)} pseudo views "
                 f"({self.plan['generator']}, {time.perf_counter() - t0:.1f} s)"
                 + (f", {seeded} Gaussians seeded where they showed nothing" if seeded else ""))

    def pseudo_weight(self, view) -> float:
        """Loss weight of one pseudo view: the ring's views past a forward-facing rig may have their own (the plan's
        "ring_weight", which is the pseudo weight unless set)."""
        return float(self.plan["ring_weight" if view.source == "surrounding" else "pseudo_weight"])

    def _warp_round(self, photos, renders, stats) -> list[torch.Tensor]:
        from gsgs_engine.priors.warp_inpaint import inpaint_all, warp_photos

        t0 = time.perf_counter()  # the generation's clock, as the diffusion round keeps its own
        warped, holes, cover = [], [], []
        for p, out in zip(self.pseudo, renders):
            img, h, s = warp_photos(p.camera, out.color, out.depth, out.alpha, _same_moment(photos, p.camera),
                                    rel_tolerance=self.cfg.warp_tolerance, fill_empty=self.fill_empty)
            warped.append(img)
            holes.append(h)
            cover.append(s)
        images = inpaint_all(warped, holes, workers=torch.get_num_threads())
        stats["warped_fraction"] = float(np.mean([s["warped"] for s in cover])) if cover else 0.0
        stats["inpainted_fraction"] = float(np.mean([s["inpainted"] for s in cover])) if cover else 0.0
        stats["empty_filled_fraction"] = float(np.mean([s["empty_filled"] for s in cover])) if cover else 0.0
        self.trainer.phase_seconds["prior_generate"] += time.perf_counter() - t0
        return images

    def _fill_empty_with_gaussians(self, renders, images, stride: int = SEED_STRIDE) -> int:
        """Seed Gaussians where pseudo views show nothing: on a grid of the empty pixels, at the depth
        filled in from the surface around them, coloured by the pseudo target. Without them the filled
        targets could only be reached by stretching the Gaussians at the edges.

        The grid is `stride` pixels at SEED_REFERENCE_SIZE px on the long side and proportionally
        coarser above, and one round adds at most max(the model's size, SEED_ROUND_MIN) Gaussians
        (an even subsample of the grid): a 100-step photo job at 1600 px had seeded 610k Gaussians onto
        514 in one round (issue 15), which no later step could train. Measured llff_flower (504 px,
        1000 steps) seeded 5.5k into a model of tens of thousands: neither bound changes it."""
        from gsgs_engine.gaussians import inverse_sigmoid, num_sh_coeffs, rgb_to_sh_dc
        from gsgs_engine.priors.warp import unproject
        from gsgs_engine.priors.warp_inpaint import fill_empty_depth, on_threads, surface_depth
        from gsgs_engine.train.densify import append_gaussians

        tr = self.trainer
        model = tr.model
        views = []  # (pseudo view, its target, its surface depth) where part of it, not all, is empty
        for p, out, img in zip(self.pseudo, renders, images):
            z = surface_depth(out.depth, out.alpha)
            empty = z <= 0
            if bool(empty.any()) and not bool(empty.all()):
                views.append((p, img, z))
        filled = on_threads(fill_empty_depth, [z for _, _, z in views], workers=torch.get_num_threads())
        points, colours, sizes = [], [], []
        for (p, img, z), zf in zip(views, filled):
            empty = z <= 0
            step = seed_stride(p.camera, stride)
            grid = torch.zeros_like(empty)
            grid[step // 2::step, step // 2::step] = True
            pick = empty & grid
            points.append(unproject(p.camera, zf)[pick])
            colours.append(img[pick])
            sizes.append(zf[pick] * step / p.camera.fx)
        if not points:
            return 0
        means, colours, sizes = torch.cat(points).float(), torch.cat(colours).float(), torch.cat(sizes).float()
        budget = max(0, min(tr.config.densify_config.max_gaussians - model.num_gaussians,
                            max(model.num_gaussians, SEED_ROUND_MIN)))
        if means.shape[0] > budget:  # the round's and the model's size caps hold for seeded Gaussians: an even subsample
            keep = torch.linspace(0, means.shape[0] - 1, budget).round().long() if budget else torch.zeros(0).long()
            means, colours, sizes = means[keep], colours[keep], sizes[keep]
        n = means.shape[0]
        if n == 0:
            return 0
        dev = model.means.device
        new = {"means": means,
               "log_scales": torch.log(sizes.clamp_min(1e-6))[:, None].repeat(1, 3),
               "quats": torch.tensor([1.0, 0.0, 0.0, 0.0]).repeat(n, 1),
               "opacity_logits": inverse_sigmoid(torch.full((n,), 0.1)),
               "sh_dc": rgb_to_sh_dc(colours.clamp(0, 1))[:, None, :],
               "sh_rest": torch.zeros(n, num_sh_coeffs(model.max_sh_degree) - 1, 3)}
        append_gaussians(model, tr.optimizer, {k: v.to(dev) for k, v in new.items()})
        tr.stats.grow(n)
        return n

    def _inverse_depth_of(self, camera, image, depth=None, alpha=None):
        from gsgs_engine.priors.depth_reg import inverse_depth

        if self.estimator is not None:
            return self.estimator(image)
        return inverse_depth(depth, alpha)

    def _diffusion_round(self, photos, renders, stats) -> list[torch.Tensor]:
        from gsgs_engine.priors.depth_reg import inverse_depth
        from gsgs_engine.priors.warp import forward_warp
        from gsgs_engine.priors.warp_inpaint import surface_depth

        tr = self.trainer
        t0 = time.perf_counter()
        samples = []
        for p, out in zip(self.pseudo, renders):
            photo = photos[p.nearest_train]
            z = surface_depth(out.depth, out.alpha)
            warped, wdepth, valid = forward_warp(out.color, z, p.camera, photo.camera, src_mask=z > 0)
            gt_inv = self._inverse_depth_of(photo.camera, photo.image, photo.depth, (photo.depth > 0).float())
            w_inv = self.estimator(warped) if self.estimator is not None else torch.where(
                valid, 1.0 / wdepth.clamp_min(1e-6), torch.zeros_like(wdepth))
            samples.append({"image": photo.image, "inverse_depth": gt_inv, "warped": warped,
                            "warped_inverse_depth": w_inv, "valid": valid})
        stats["lora"] = self.diffusion.adapt(samples, use_geo=self.plan.get("geo_loss", True))
        t1 = time.perf_counter()
        tr.phase_seconds["prior_adapt"] += t1 - t0
        images = []
        for j, (p, out) in enumerate(zip(self.pseudo, renders)):
            inv = self._inverse_depth_of(p.camera, out.color, out.depth, out.alpha)
            images.append(self.diffusion.generate(out.color, inv, seed=1000 * self.rounds_done + j))
        tr.phase_seconds["prior_generate"] += time.perf_counter() - t1
        self.diffusion.save_lora(self.out_dir / "pseudo" / f"round_{self.rounds_done}" / "lora.safetensors")
        return images

    def _save_round(self, k: int, images, renders, stats) -> None:
        from gsgs_engine.priors.depth_reg import inverse_depth
        from gsgs_engine.priors.warp_inpaint import on_threads

        folder = self.out_dir / "pseudo" / f"round_{k}"
        pictures = []  # (path, the image it shows): written on the process's threads (PNG encoding drops the GIL)
        for j, (p, img, out) in enumerate(zip(self.pseudo, images, renders)):
            pictures.append((folder / f"{p.name}.png", _to_u8(img)))
            pictures.append((folder / f"{p.name}_render.png", _to_u8(out.color)))
            pictures.append((folder / f"{p.name}_depth.png", _depth_png(inverse_depth(out.depth, out.alpha))))
            if self.pseudo_depth:
                pictures.append((folder / f"{p.name}_depth_estimate.png", _depth_png(*self.pseudo_depth[j])))
        on_threads(lambda item: _save_png(*item), pictures, workers=torch.get_num_threads())
        from gsgs_engine.io.world_scale import camera_dicts_to_world

        cams = camera_dicts_to_world([{"name": p.name, "nearest_train": p.nearest_train, "source": p.source,
                                       **p.camera.to_dict()} for p in self.pseudo],
                                     getattr(self.trainer.scene, "world_scale", 1.0))  # what the user's scene measures
        (folder / "round.json").write_text(json.dumps({**stats, "views": cams}, indent=1))
