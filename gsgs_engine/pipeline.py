"""Algorithm 1: warm-up, then rounds of render -> adapt -> generate -> optimise (eq. 5, 11).

`run_prior_training` wraps the plain trainer (gsgs_engine.train.trainer) with the GS-GS
prior: pseudo views (priors/poses.py), a generator (warp-inpaint, or diffusion + LoRA with
the geometry-aware loss), and the depth regulariser (eq. 10) as an extra loss term. Every
round's pseudo images and depths go to OUT/pseudo/round_k/ (the "dataset evolution").
`resolve_prior_plan` decides, before training, which of these effects run and why.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from gsgs_engine import GsgsError

PRIOR_CHOICES = ("none", "depth", "warp", "diffusion", "auto")
MIN_DEPTH_COVERAGE = 0.10  # share of training-view pixels a depth source must cover to regularise


@dataclass
class PriorConfig:
    prior: str = "auto"
    depth_source: str = "auto"  # auto | none | sparse | a local depth-estimation model folder
    num_pseudo: int = 16
    rounds: int = 3
    warmup_fraction: float = 0.3  # share of the iterations before the first round
    pseudo_weight: float = 0.5  # loss weight of a pseudo view relative to a real one (eq. 11)
    lambda_reg: float = 0.1  # weight of L_reg (eq. 10, 11)
    depth_reg: bool = True
    geo_loss: bool = True
    jitter: float = 0.0
    reach: float = 3.0  # forward-facing rigs: half the pseudo views on a ring of reach x the rig's radius (0 = none)
    diffusion_model: str | None = None
    depth_adapter: str | None = None
    diffusion: dict = field(default_factory=dict)  # DiffusionSettings overrides (steps, strength, ...)
    device: str = "auto"

    def to_dict(self) -> dict:
        return asdict(self)


def diffusion_configured(cfg: PriorConfig) -> bool:
    return bool(cfg.diffusion_model and cfg.depth_adapter and Path(cfg.diffusion_model).is_dir()
                and Path(cfg.depth_adapter).is_dir())


def resolve_prior_plan(cfg: PriorConfig, num_train_views: int, sparse_points: int | None = None) -> dict:
    """Which effects run, from the request and what is available; every choice says why."""
    if cfg.prior not in PRIOR_CHOICES:
        raise GsgsError(f"--prior {cfg.prior!r}: choose one of {', '.join(PRIOR_CHOICES)}")
    plan: dict = {"requested": cfg.prior}
    if cfg.prior == "none":
        return {**plan, "prior": "none", "generator": None, "depth_source": None, "pseudo_views": 0,
                "reason": "plain 3DGS requested"}
    has_diffusion = diffusion_configured(cfg)
    if cfg.prior == "diffusion" and not has_diffusion:
        raise GsgsError("--prior diffusion needs local model folders: --diffusion-model (Stable Diffusion 1.5 "
                        "layout) and --depth-adapter (a depth T2I-Adapter); or use --prior warp / auto")
    generator = {"depth": None, "warp": "warp-inpaint", "diffusion": "diffusion"}.get(cfg.prior)
    if cfg.prior == "auto":
        generator = "diffusion" if has_diffusion else "warp-inpaint"
        plan["generator_reason"] = ("diffusion weights configured" if has_diffusion
                                    else "no diffusion weights configured: the weights-free warp-inpaint generator")
    # depth source: a model folder beats SfM points; none disables the regulariser
    src = cfg.depth_source
    if not cfg.depth_reg:
        depth_source, why = None, "--no-depth-reg"
    elif src not in ("auto", "none", "sparse"):
        if not Path(src).is_dir():
            raise GsgsError(f"--depth-source {src!r}: folder not found; give a local depth-estimation model folder, "
                            "'sparse', 'none' or 'auto'")
        depth_source, why = src, "depth-estimation model folder"
    elif src == "none":
        depth_source, why = None, "--depth-source none"
    elif sparse_points is not None and sparse_points < 50:
        depth_source, why = None, f"no depth model configured and only {sparse_points} SfM points"
        if cfg.prior == "depth":
            raise GsgsError("--prior depth needs a depth source: --depth-source MODEL_DIR, or enough SfM points")
    else:
        depth_source, why = "sparse", "no depth model configured: SfM points of the training views, image-guided"
    if cfg.prior == "depth" and depth_source is None:
        raise GsgsError("--prior depth needs a depth source (--depth-source sparse or a model folder)")
    pseudo = 0 if generator is None else cfg.num_pseudo
    return {**plan, "prior": cfg.prior if cfg.prior != "auto" else f"auto:{generator}", "generator": generator,
            "depth_source": depth_source, "depth_source_reason": why, "pseudo_views": pseudo,
            "rounds": cfg.rounds if generator else 0, "warmup_fraction": cfg.warmup_fraction,
            "pseudo_weight": cfg.pseudo_weight, "lambda_reg": cfg.lambda_reg if depth_source else 0.0,
            "geo_loss": bool(cfg.geo_loss and generator == "diffusion"), "jitter": cfg.jitter,
            "reach": cfg.reach,
            "depth_convention": "inverse depth (rendered 1/z vs estimated relative inverse depth)"}


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
    from gsgs_engine.effect_plan import focus_point

    if len(cameras) < 2:
        return None
    focus, how = focus_point(cameras)
    return focus if how == "optical axes intersection" else None


class PriorLoop:
    """Installs itself on a Trainer: pseudo views, rounds, and the depth-regulariser loss term."""

    def __init__(self, cfg: PriorConfig, plan: dict, out_dir: Path, log=print):
        self.cfg = cfg
        self.plan = plan
        self.out_dir = Path(out_dir)
        self.log = log
        self.rounds_done = 0
        self.round_stats: list[dict] = []
        self.train_depth: list[tuple[torch.Tensor, torch.Tensor]] = []
        self.pseudo_depth: list[tuple[torch.Tensor, torch.Tensor]] = []
        self.estimator = None
        self.sparse = None
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
            # forward-facing rigs: half the views on a ring past the rig's edges, the other half between
            # neighbouring cameras. (Orbits: all between neighbours; views placed in an orbit's widest gaps
            # measured worse on lego_200, 21.65 vs 22.02 dB: warps across those gaps are too far off.)
            ring = self.cfg.num_pseudo // 2 if (focus is None and self.cfg.reach > 0) else 0
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
        self._setup_depth_source(trainer)
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
        if self.plan.get("depth_source"):
            trainer.loss_terms["depth_reg"] = self.depth_term
        trainer.callbacks.append(self.on_step)
        self.plan["round_steps"] = self.steps
        # A resumed run past the warm-up regenerates the current round from the restored model.
        if self.pseudo and self.steps and trainer.step >= self.steps[0]:
            self.rounds_done = sum(1 for s in self.steps if s <= trainer.step) - 1
            self.run_round()

    def _setup_depth_source(self, trainer) -> None:
        src = self.plan.get("depth_source")
        if not src:
            return
        if src == "sparse":
            from gsgs_engine.priors.sparse_depth import SparseDepthSource

            points = self.plan.pop("_sparse_points", None)
            if points is None:
                from gsgs_engine.sfm import triangulate_known_poses

                points, _ = triangulate_known_poses(trainer.train_views)
            self.sparse = SparseDepthSource(points)
            self.plan["sparse_points"] = int(len(self.sparse.points))
        else:
            from gsgs_engine.priors.depth_estimators import load_depth_estimator

            self.estimator = load_depth_estimator(src, device=str(trainer.device))
        self.train_depth = [self.estimate(v.camera, trainer._targets[i]) for i, v in enumerate(trainer.train_views)]
        coverage = float(np.mean([float(m.float().mean()) for _, m in self.train_depth]))
        self.plan["depth_coverage"] = round(coverage, 4)
        if coverage < MIN_DEPTH_COVERAGE:
            # A depth map known on a few scattered pixels constrains nothing and adds noise.
            self.plan["depth_source_disabled"] = (f"the {src} depth covers {coverage:.1%} of the training views "
                                                  f"(< {MIN_DEPTH_COVERAGE:.0%})")
            self.plan["depth_source"] = None
            self.plan["lambda_reg"] = 0.0
            self.train_depth = []
            self.log(f"depth regulariser off: {self.plan['depth_source_disabled']}")

    def estimate(self, camera, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(relative inverse depth, valid mask) of an image at a camera from the configured source,
        on the trainer's device (the depth sources answer on the CPU)."""
        if self.sparse is not None:
            inv, mask = self.sparse.estimate(camera, image)
        else:
            inv = self.estimator(image)
            mask = torch.isfinite(inv)
        device = self.trainer.device
        return inv.to(device), mask.to(device)

    # -- eq. 10 as a loss term ------------------------------------------------------------
    def depth_term(self, ctx):
        from gsgs_engine.priors.depth_reg import depth_regulariser, inverse_depth

        terms = []
        inv_t, mask_t = self.train_depth[ctx.view_index]
        if mask_t.sum() > 16:
            rendered = inverse_depth(ctx.render.depth, ctx.render.alpha)
            terms.append(depth_regulariser(rendered, inv_t, mask_t))
        if ctx.pseudo is not None and self.pseudo_depth:
            k = next(i for i, pv in enumerate(ctx.trainer.pseudo_views) if pv is ctx.pseudo)
            inv_p, mask_p = self.pseudo_depth[self.active[k]]
            if mask_p.sum() > 16:
                rendered = inverse_depth(ctx.pseudo_render.depth, ctx.pseudo_render.alpha)
                terms.append(depth_regulariser(rendered, inv_p, mask_p))
        if not terms:
            return None
        return self.cfg.lambda_reg, torch.stack(terms).mean()

    # -- Alg. 1 rounds ----------------------------------------------------------------------
    def on_step(self, trainer, step: int) -> None:
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
        from gsgs_engine.train.trainer import PseudoView as TrainerPseudoView

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
        if self.plan.get("depth_source"):
            self.pseudo_depth = [self.estimate(p.camera, img) for p, img in zip(self.pseudo, images)]
        # A pseudo view the model barely covers carries no surface to supervise: leave it out this round
        # (right after an opacity reset, say); unless empty is unseen content, which the round fills.
        train_cover = float(np.median([float((ph.depth > 0).float().mean()) for ph in photos]))
        keep = [self.fill_empty or float((out.alpha > 0.5).float().mean()) >= 0.5 * train_cover for out in renders]
        if self.fill_empty:
            stats["gaussians_added_in_empty"] = self._fill_empty_with_gaussians(renders, images)
        stats["pseudo_views_used"] = int(sum(keep))
        stats["pseudo_views_skipped_low_coverage"] = len(keep) - int(sum(keep))
        self.active = [j for j, k in enumerate(keep) if k]
        tr.set_pseudo_views([TrainerPseudoView(camera=self.pseudo[j].camera, image=images[j], weight=self.cfg.pseudo_weight,
                                               name=self.pseudo[j].name, nearest_train=self.pseudo[j].nearest_train)
                             for j in self.active])
        tr.phase_seconds["prior_generate"] += time.perf_counter() - t2
        self._save_round(k, images, renders, stats)
        self.rounds_done += 1
        self.round_stats.append(stats)
        seeded = stats.get("gaussians_added_in_empty", 0)
        self.log(f"prior round {k + 1}/{len(self.steps)} at step {tr.step}: {len(images)} pseudo views "
                 f"({self.plan['generator']}, {time.perf_counter() - t0:.1f} s)"
                 + (f", {seeded} Gaussians seeded where they showed nothing" if seeded else ""))

    def _warp_round(self, photos, renders, stats) -> list[torch.Tensor]:
        from gsgs_engine.priors.warp_inpaint import warp_inpaint

        images, cover = [], []
        for p, out in zip(self.pseudo, renders):
            img, s = warp_inpaint(p.camera, out.color, out.depth, out.alpha, _same_moment(photos, p.camera),
                                  fill_empty=self.fill_empty)
            images.append(img)
            cover.append(s)
        stats["warped_fraction"] = float(np.mean([s["warped"] for s in cover])) if cover else 0.0
        stats["inpainted_fraction"] = float(np.mean([s["inpainted"] for s in cover])) if cover else 0.0
        stats["empty_filled_fraction"] = float(np.mean([s["empty_filled"] for s in cover])) if cover else 0.0
        return images

    def _fill_empty_with_gaussians(self, renders, images, stride: int = 4) -> int:
        """Seed Gaussians where pseudo views show nothing: on a `stride`-pixel grid of the empty pixels,
        at the depth filled in from the surface around them, coloured by the pseudo target. Without
        them the filled targets could only be reached by stretching the Gaussians at the edges."""
        from gsgs_engine.gaussians import inverse_sigmoid, num_sh_coeffs, rgb_to_sh_dc
        from gsgs_engine.priors.warp import unproject
        from gsgs_engine.priors.warp_inpaint import fill_empty_depth, surface_depth
        from gsgs_engine.train.densify import append_gaussians

        tr = self.trainer
        model = tr.model
        points, colours, sizes = [], [], []
        for p, out, img in zip(self.pseudo, renders, images):
            z = surface_depth(out.depth, out.alpha)
            empty = z <= 0
            if not bool(empty.any()) or bool(empty.all()):
                continue
            zf = fill_empty_depth(z)
            grid = torch.zeros_like(empty)
            grid[stride // 2::stride, stride // 2::stride] = True
            pick = empty & grid
            points.append(unproject(p.camera, zf)[pick])
            colours.append(img[pick])
            sizes.append(zf[pick] * stride / p.camera.fx)
        if not points:
            return 0
        means, colours, sizes = torch.cat(points).float(), torch.cat(colours).float(), torch.cat(sizes).float()
        budget = max(0, tr.config.densify_config.max_gaussians - model.num_gaussians)
        if means.shape[0] > budget:  # the model's size cap holds for seeded Gaussians too: an even subsample
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

        folder = self.out_dir / "pseudo" / f"round_{k}"
        for j, (p, img, out) in enumerate(zip(self.pseudo, images, renders)):
            _save_png(folder / f"{p.name}.png", _to_u8(img))
            _save_png(folder / f"{p.name}_render.png", _to_u8(out.color))
            _save_png(folder / f"{p.name}_depth.png", _depth_png(inverse_depth(out.depth, out.alpha)))
            if self.pseudo_depth:
                _save_png(folder / f"{p.name}_depth_estimate.png", _depth_png(*self.pseudo_depth[j]))
        cams = [{"name": p.name, "nearest_train": p.nearest_train, "source": p.source, **p.camera.to_dict()}
                for p in self.pseudo]
        (folder / "round.json").write_text(json.dumps({**stats, "views": cams}, indent=1))


def run_prior_training(scene, train_config, prior_config: PriorConfig, out_dir, checkpoint_dir, job=None,
                       resume: bool = False, plan: dict | None = None, authored_poses: list | None = None,
                       stream=None) -> dict:
    """Train with the GS-GS prior (or plainly when the plan says none); returns metrics.json's dict."""
    from gsgs_engine.train.trainer import train_and_export

    prior_plan = resolve_prior_plan(prior_config, len(scene.train))
    prior_plan["authored_poses"] = list(authored_poses or [])
    loop_holder: dict = {}

    def setup(trainer) -> None:
        if prior_plan["generator"] is None and not prior_plan.get("depth_source"):
            return
        if prior_plan.get("depth_source") == "sparse" and trainer.init_info.method in ("sfm", "points") and trainer.step == 0:
            prior_plan["_sparse_points"] = trainer.model.means.detach().cpu().numpy().copy()
        loop = PriorLoop(prior_config, prior_plan, Path(out_dir), log=trainer.log)
        loop.install(trainer)
        loop_holder["loop"] = loop

    merged = dict(plan or {})
    metrics = train_and_export(scene, train_config, out_dir, checkpoint_dir, job=job, resume=resume,
                               plan={**merged, "prior": prior_plan["prior"]}, stream=stream,
                               setup_trainer=setup)
    loop = loop_holder.get("loop")
    prior_plan.pop("_sparse_points", None)
    prior_plan["authored_poses"] = len(prior_plan["authored_poses"])
    metrics["plan"]["prior_plan"] = prior_plan
    if loop is not None:
        metrics["prior_rounds"] = loop.round_stats
    from gsgs_engine.job import write_json_atomic

    write_json_atomic(Path(out_dir) / "metrics.json", metrics)
    return metrics


# -- command-line and job settings -----------------------------------------------------------
def add_prior_arguments(parser) -> None:
    """The prior's options of `gsgs train` (the switches reproduce the paper's ablation rows)."""
    g = parser.add_argument_group("generative prior (GS-GS)")
    g.add_argument("--pseudo-views", type=int, default=PriorConfig.num_pseudo, help="number of pseudo views")
    g.add_argument("--rounds", type=int, default=PriorConfig.rounds, help="rounds of render -> adapt -> generate")
    g.add_argument("--warmup-fraction", type=float, default=PriorConfig.warmup_fraction,
                   help="share of the iterations trained on the real views before the first round")
    g.add_argument("--pseudo-weight", type=float, default=PriorConfig.pseudo_weight,
                   help="loss weight of a pseudo view relative to a real one")
    g.add_argument("--lambda-reg", type=float, default=PriorConfig.lambda_reg, help="weight of the depth term (eq. 10)")
    g.add_argument("--depth-source", default="auto",
                   help="auto | none | sparse | a local depth-estimation model folder (DPT layout)")
    g.add_argument("--no-depth-reg", action="store_true", help="disable the depth regulariser (ablation)")
    g.add_argument("--no-geo-loss", action="store_true", help="disable the geometry-aware LoRA loss (ablation)")
    g.add_argument("--pseudo-jitter", type=float, default=0.0, help="relative jitter of the pseudo poses")
    g.add_argument("--pseudo-reach", type=float, default=PriorConfig.reach,
                   help="forward-facing rigs: half the pseudo views on a ring of this many rig radii around the "
                        "cameras, past the rig's edges (0 = all between neighbouring cameras)")
    g.add_argument("--diffusion-model", default=None, help="local Stable Diffusion 1.5 folder (diffusers layout)")
    g.add_argument("--depth-adapter", default=None, help="local depth T2I-Adapter folder")
    g.add_argument("--diffusion-strength", type=float, default=0.6,
                   help="1.0 = generate from noise; < 1 = start from the partially noised render")
    g.add_argument("--diffusion-steps", type=int, default=20)
    g.add_argument("--diffusion-resolution", type=int, default=512)
    g.add_argument("--lora-steps", type=int, default=50)
    g.add_argument("--device", default="auto", help="device of the diffusion prior: auto | cpu | cuda")


def prior_config_from_args(args) -> PriorConfig:
    return PriorConfig(prior=args.prior, depth_source=args.depth_source, num_pseudo=args.pseudo_views,
                       rounds=args.rounds, warmup_fraction=args.warmup_fraction, pseudo_weight=args.pseudo_weight,
                       lambda_reg=args.lambda_reg, depth_reg=not args.no_depth_reg, geo_loss=not args.no_geo_loss,
                       jitter=args.pseudo_jitter, reach=args.pseudo_reach, diffusion_model=args.diffusion_model,
                       depth_adapter=args.depth_adapter, device=args.device,
                       diffusion={"strength": args.diffusion_strength, "steps": args.diffusion_steps,
                                  "resolution": args.diffusion_resolution, "lora_steps": args.lora_steps})


def prior_config_from_settings(settings: dict) -> PriorConfig:
    """job.json settings -> PriorConfig (keys named as PriorConfig's fields; unknown keys refused).

    A "preset" fills the keys the job leaves out (gsgs_engine.job.settings_with_preset)."""
    from gsgs_engine.job import settings_with_preset

    settings = settings_with_preset(settings)
    known = set(PriorConfig.__dataclass_fields__)
    d = {k: v for k, v in (settings.get("prior_settings") or {}).items()}
    unknown = sorted(set(d) - known)
    if unknown:
        raise GsgsError(f"job.json: unknown prior settings {unknown}; known: {sorted(known)}")
    return PriorConfig(prior=settings.get("prior", "none") or "none", **d)
