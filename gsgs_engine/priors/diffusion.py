"""The diffusion prior: depth-conditioned latent diffusion, adapted per scene with LoRA.

Stable Diffusion 1.5-class components + a depth T2I-Adapter (diffusers), LoRA on the UNet
attention projections (peft). Only LoRA weights train. Paper eq. 4 (L_LDM), eq. 6 (LoRA
objective with the geometry-aware DIFT feature term) and the depth-conditioned
generation at pseudo views live here, each in one named method. Weights come from local
folders only; `tiny_diffusion.save_tiny_diffusion` writes test-sized models of the same
classes. fp16 on CUDA (LoRA weights kept in fp32), fp32 on the CPU.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import torch
import torch.nn.functional as F

from gsgs_engine import GsgsError

LORA_TARGETS = ["to_q", "to_k", "to_v", "to_out.0"]


@dataclass
class DiffusionSettings:
    model_dir: str  # Stable Diffusion 1.5 layout: unet/ vae/ text_encoder/ tokenizer/ scheduler/
    adapter_dir: str  # depth T2I-Adapter folder
    prompt: str = "a photo of the scene, high quality, detailed"
    negative_prompt: str = "blurry, low quality"
    steps: int = 20
    strength: float = 0.6  # 1.0 = start from pure noise (hallucinate more); < 1 = img2img from the render
    guidance: float = 5.0
    resolution: int = 512  # long side of the working resolution
    lora_rank: int = 4
    lora_steps: int = 50  # LoRA optimisation steps per round
    lora_lr: float = 1e-4
    lambda_geo: float = 0.1  # eq. 6
    dift_timestep: int = 261  # DIFT's small fixed noise level for features
    dift_up_block: int = 1  # which UNet up-block's output serves as features
    device: str = "auto"
    seed: int = 0
    extra: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k != "extra"}


def _resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


class DiffusionPrior:
    """Loads the components once; `adapt` fine-tunes LoRA (eq. 6); `generate` hallucinates a view."""

    def __init__(self, settings: DiffusionSettings):
        self.s = settings
        for label, path in (("diffusion model", settings.model_dir), ("depth adapter", settings.adapter_dir)):
            if not path or not Path(path).is_dir():
                raise GsgsError(f"{path!r}: {label} folder not found; set it in the add-on preferences or with "
                                f"--diffusion-model / --depth-adapter (local folders in the diffusers layout)")
        missing = [sub for sub in ("unet", "vae", "text_encoder", "tokenizer", "scheduler")
                   if not (Path(settings.model_dir) / sub).is_dir()]
        if missing:
            raise GsgsError(f"{settings.model_dir}: missing {', '.join(missing)}; expected a Stable Diffusion 1.5 "
                            "folder in the diffusers layout")
        os.environ.setdefault("HF_HUB_OFFLINE", "1")
        from diffusers import AutoencoderKL, DDIMScheduler, T2IAdapter, UNet2DConditionModel
        from peft import LoraConfig
        from transformers import CLIPTextModel, CLIPTokenizer

        self.device = _resolve_device(settings.device)
        self.dtype = torch.float16 if self.device.type == "cuda" else torch.float32
        md = settings.model_dir
        # safetensors only: a model folder may come from anywhere, and a pickled .bin can run code when loaded
        kw = {"local_files_only": True, "torch_dtype": self.dtype, "use_safetensors": True}
        self.unet = UNet2DConditionModel.from_pretrained(md, subfolder="unet", **kw)
        self.vae = AutoencoderKL.from_pretrained(md, subfolder="vae", **kw)
        self.text_encoder = CLIPTextModel.from_pretrained(md, subfolder="text_encoder", **kw)
        self.tokenizer = CLIPTokenizer.from_pretrained(md, subfolder="tokenizer", local_files_only=True)
        self.scheduler = DDIMScheduler.from_pretrained(md, subfolder="scheduler", local_files_only=True)
        self.adapter = T2IAdapter.from_pretrained(settings.adapter_dir, **kw)
        for module in (self.unet, self.vae, self.text_encoder, self.adapter):
            module.requires_grad_(False)
            module.to(self.device)
            module.eval()
        self.unet.add_adapter(LoraConfig(r=settings.lora_rank, lora_alpha=settings.lora_rank,
                                         init_lora_weights="gaussian", target_modules=LORA_TARGETS))
        self.lora_params = [p for p in self.unet.parameters() if p.requires_grad]
        for p in self.lora_params:  # train LoRA in fp32 even when the frozen model is fp16
            p.data = p.data.float()
        self.optimizer = torch.optim.AdamW(self.lora_params, lr=settings.lora_lr)
        self.vae_factor = 2 ** (len(self.vae.config.block_out_channels) - 1)
        self.multiple = self.vae_factor * 2 ** (len(self.unet.config.block_out_channels) - 1)
        self.generator = torch.Generator(device="cpu").manual_seed(settings.seed)
        with torch.no_grad():
            self.cond_embedding = self._encode_prompt(settings.prompt)
            self.uncond_embedding = self._encode_prompt(settings.negative_prompt)

    # -- helpers --------------------------------------------------------------------
    def _encode_prompt(self, prompt: str) -> torch.Tensor:
        ids = self.tokenizer([prompt], padding="max_length", max_length=self.tokenizer.model_max_length,
                             truncation=True, return_tensors="pt").input_ids.to(self.device)
        return self.text_encoder(ids)[0].to(self.dtype)

    def working_size(self, height: int, width: int) -> tuple[int, int]:
        scale = self.s.resolution / max(height, width)
        h = max(self.multiple, int(round(height * scale / self.multiple)) * self.multiple)
        w = max(self.multiple, int(round(width * scale / self.multiple)) * self.multiple)
        return h, w

    def _to_model(self, image: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
        """(H, W, 3) in [0, 1] -> (1, 3, h, w) in [-1, 1] at the working size."""
        x = image.permute(2, 0, 1)[None].float().to(self.device)
        x = F.interpolate(x, size=size, mode="bilinear", align_corners=False, antialias=True)
        return (x * 2 - 1).to(self.dtype)

    def depth_condition(self, inverse_depth: torch.Tensor, size: tuple[int, int],
                        mask: torch.Tensor | None = None) -> torch.Tensor:
        """Relative inverse depth (H, W) -> the adapter's 3-channel [0, 1] image (near = bright)."""
        d = inverse_depth.float().to(self.device)
        valid = torch.isfinite(d) if mask is None else (mask.to(self.device).bool() & torch.isfinite(d))
        if valid.any():
            lo, hi = d[valid].min(), d[valid].max()
            d = torch.where(valid, (d - lo) / (hi - lo).clamp_min(1e-6), torch.zeros_like(d))
        else:
            d = torch.zeros_like(d)
        d = F.interpolate(d[None, None], size=size, mode="bilinear", align_corners=False)
        return d.expand(1, 3, *size).to(self.dtype)

    def _latents(self, x: torch.Tensor, sample: bool = True) -> torch.Tensor:
        dist = self.vae.encode(x).latent_dist
        return (dist.sample(self.generator) if sample else dist.mean) * self.vae.config.scaling_factor

    def _unet(self, latents: torch.Tensor, t: torch.Tensor, embedding: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        residuals = [f for f in self.adapter(cond)]
        with self._autocast():
            return self.unet(latents, t, embedding, down_intrablock_additional_residuals=residuals).sample.float()

    def _autocast(self):
        if self.device.type == "cuda":
            return torch.autocast("cuda", dtype=torch.float16)
        return torch.autocast("cpu", enabled=False)

    # -- eq. 4 ------------------------------------------------------------------------
    def ldm_loss(self, image: torch.Tensor, inverse_depth: torch.Tensor) -> torch.Tensor:
        """L_LDM (eq. 4): predict the noise added to the image's latent, conditioned on its depth."""
        size = self.working_size(*image.shape[:2])
        with torch.no_grad():
            latents = self._latents(self._to_model(image, size))
            cond = self.depth_condition(inverse_depth, size)
        noise = torch.randn(latents.shape, generator=self.generator).to(self.device, latents.dtype)
        t = torch.randint(0, self.scheduler.config.num_train_timesteps, (1,), generator=self.generator).to(self.device)
        noisy = self.scheduler.add_noise(latents, noise, t)
        target = noise if self.scheduler.config.prediction_type == "epsilon" else self.scheduler.get_velocity(latents, noise, t)
        pred = self._unet(noisy, t, self.cond_embedding, cond)
        return F.mse_loss(pred, target.float())

    # -- DIFT features and the geometry-aware term of eq. 6 ------------------------------
    def dift_features(self, image: torch.Tensor, inverse_depth: torch.Tensor, seed: int = 0) -> torch.Tensor:
        """Features of one UNet up-block after a fixed small noise (DIFT), with the adapter condition."""
        size = self.working_size(*image.shape[:2])
        with torch.no_grad():
            latents = self._latents(self._to_model(image, size), sample=False)
            cond = self.depth_condition(inverse_depth, size)
        g = torch.Generator(device="cpu").manual_seed(seed)
        noise = torch.randn(latents.shape, generator=g).to(self.device, latents.dtype)
        t = torch.tensor([self.s.dift_timestep], device=self.device)
        noisy = self.scheduler.add_noise(latents, noise, t)
        captured: list[torch.Tensor] = []
        block = self.unet.up_blocks[min(self.s.dift_up_block, len(self.unet.up_blocks) - 1)]
        handle = block.register_forward_hook(lambda _m, _i, out: captured.append(out))
        try:
            self._unet(noisy, t, self.cond_embedding, cond)
        finally:
            handle.remove()
        return captured[0].float()

    def geometry_loss(self, gt_image: torch.Tensor, gt_inverse_depth: torch.Tensor, warped_render: torch.Tensor,
                      warped_inverse_depth: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
        """|| f_train - f'_train ||_1 over the valid warp mask (eq. 6, third term)."""
        f_gt = self.dift_features(gt_image, gt_inverse_depth)
        f_warp = self.dift_features(warped_render, warped_inverse_depth)
        m = F.interpolate(valid.float()[None, None].to(self.device), size=f_gt.shape[-2:], mode="area")
        m = (m > 0.5).float()
        return ((f_gt - f_warp).abs() * m).sum() / (m.sum() * f_gt.shape[1]).clamp_min(1.0)

    def adapt(self, samples: list[dict], steps: int | None = None, use_geo: bool = True, progress=None) -> dict:
        """Fine-tune LoRA with eq. 6 over `samples`.

        Each sample: {"image", "inverse_depth"} (a training view: GT image and its depth), plus,
        for the geometry-aware term, {"warped", "warped_inverse_depth", "valid"} (a pseudo render
        warped into that training view).
        """
        steps = self.s.lora_steps if steps is None else steps
        totals = {"ldm": 0.0, "ldm_warped": 0.0, "geo": 0.0}
        self.unet.train()
        for step in range(steps):
            sample = samples[int(torch.randint(0, len(samples), (1,), generator=self.generator))]
            loss = self.ldm_loss(sample["image"], sample["inverse_depth"])
            totals["ldm"] += loss.item()
            if "warped" in sample:
                l_w = self.ldm_loss(sample["warped"], sample["warped_inverse_depth"])
                totals["ldm_warped"] += l_w.item()
                loss = loss + l_w
                if use_geo and self.s.lambda_geo > 0 and sample["valid"].any():
                    l_geo = self.geometry_loss(sample["image"], sample["inverse_depth"], sample["warped"],
                                               sample["warped_inverse_depth"], sample["valid"])
                    totals["geo"] += l_geo.item()
                    loss = loss + self.s.lambda_geo * l_geo
            self.optimizer.zero_grad(set_to_none=True)
            if torch.isfinite(loss):
                loss.backward()
                torch.nn.utils.clip_grad_norm_(self.lora_params, 1.0)
                self.optimizer.step()
            if progress is not None:
                progress(step + 1, steps, loss.item())
        self.unet.eval()
        return {k: v / max(steps, 1) for k, v in totals.items()}

    # -- generation at a pseudo view ---------------------------------------------------
    @torch.no_grad()
    def generate(self, render: torch.Tensor, inverse_depth: torch.Tensor, seed: int = 0,
                 strength: float | None = None) -> torch.Tensor:
        """A new image (H, W, 3) in [0, 1] for a pseudo view, conditioned on its depth.

        strength < 1 starts from the partially noised render (keeps layout); 1.0 starts from noise.
        """
        strength = self.s.strength if strength is None else strength
        h, w = render.shape[:2]
        size = self.working_size(h, w)
        cond = self.depth_condition(inverse_depth, size)
        g = torch.Generator(device="cpu").manual_seed(seed)
        self.scheduler.set_timesteps(self.s.steps, device=self.device)
        timesteps = self.scheduler.timesteps
        latent_shape = (1, self.unet.config.in_channels, size[0] // self.vae_factor, size[1] // self.vae_factor)
        noise = torch.randn(latent_shape, generator=g).to(self.device, self.dtype)
        if strength < 1.0:
            start = min(int(round(self.s.steps * (1.0 - strength))), len(timesteps) - 1)
            timesteps = timesteps[start:]
            init = self.vae.encode(self._to_model(render, size)).latent_dist.mean * self.vae.config.scaling_factor
            latents = self.scheduler.add_noise(init, noise, timesteps[:1])
        else:
            latents = noise * self.scheduler.init_noise_sigma
        embeddings = torch.cat([self.uncond_embedding, self.cond_embedding])
        cond2 = torch.cat([cond, cond])
        for t in timesteps:
            eps = self._unet(torch.cat([latents, latents]), t, embeddings, cond2)
            eps_u, eps_c = eps.chunk(2)
            eps = eps_u + self.s.guidance * (eps_c - eps_u)
            latents = self.scheduler.step(eps.to(latents.dtype), t, latents).prev_sample
        image = self.vae.decode(latents / self.vae.config.scaling_factor).sample.float()
        image = F.interpolate((image + 1) / 2, size=(h, w), mode="bilinear", align_corners=False, antialias=True)
        return image[0].permute(1, 2, 0).clamp(0, 1).cpu()

    def save_lora(self, path: str | os.PathLike) -> None:
        from peft.utils import get_peft_model_state_dict
        from safetensors.torch import save_file

        state = {k: v.detach().float().cpu().contiguous() for k, v in get_peft_model_state_dict(self.unet).items()}
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        save_file(state, str(path))

    def load_lora(self, path: str | os.PathLike) -> None:
        from peft.utils import set_peft_model_state_dict
        from safetensors.torch import load_file

        set_peft_model_state_dict(self.unet, load_file(str(path)))
