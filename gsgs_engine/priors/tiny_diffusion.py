"""Tiny, randomly initialised stand-ins for Stable Diffusion 1.5 + a depth T2I-Adapter.

They are the same diffusers / transformers classes as the real models, saved in the real
folder layouts, so the loading, LoRA adaptation (eq. 4, 6) and generation code paths run
end to end in seconds on a CPU. Their images are noise-like: they test wiring, never
quality. The real weights cannot be downloaded here; users point the settings at local
copies (DESIGN.md "Where weights come from").
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import torch


def _byte_alphabet() -> list[str]:
    """The 256 printable stand-ins byte-level BPE uses for raw bytes (GPT-2 / CLIP scheme)."""
    keep = list(range(ord("!"), ord("~") + 1)) + list(range(ord("¡"), ord("¬") + 1)) + list(range(ord("®"), ord("ÿ") + 1))
    chars, extra = [], 0
    for b in range(256):
        if b in keep:
            chars.append(chr(b))
        else:
            chars.append(chr(256 + extra))
            extra += 1
    return chars


def _write_byte_level_tokenizer(folder: Path) -> None:
    """A valid CLIP BPE tokenizer with a byte-level vocabulary and no merges."""
    from transformers import CLIPTokenizer

    chars = _byte_alphabet()
    vocab = {}
    for c in chars:
        vocab[c] = len(vocab)
    for c in chars:
        vocab[c + "</w>"] = len(vocab)
    vocab["<|startoftext|>"] = len(vocab)
    vocab["<|endoftext|>"] = len(vocab)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "vocab.json").write_text(json.dumps(vocab))
    (folder / "merges.txt").write_text("#version: 0.2\n")
    tok = CLIPTokenizer(vocab_file=str(folder / "vocab.json"), merges_file=str(folder / "merges.txt"), model_max_length=16)
    tok.save_pretrained(folder)


def save_tiny_diffusion(root: str | os.PathLike, seed: int = 0) -> tuple[Path, Path]:
    """Write a tiny SD-1.5-layout folder and a tiny depth T2I-Adapter folder; return both paths."""
    from diffusers import AutoencoderKL, DDIMScheduler, T2IAdapter, UNet2DConditionModel
    from transformers import CLIPTextConfig, CLIPTextModel

    torch.manual_seed(seed)
    root = Path(root)
    sd, adapter_dir = root / "sd", root / "depth_adapter"
    channels = (32, 64)
    UNet2DConditionModel(
        sample_size=16, in_channels=4, out_channels=4, layers_per_block=1, block_out_channels=channels,
        down_block_types=("CrossAttnDownBlock2D", "DownBlock2D"), up_block_types=("UpBlock2D", "CrossAttnUpBlock2D"),
        cross_attention_dim=32, attention_head_dim=8, norm_num_groups=8,
    ).save_pretrained(sd / "unet")
    AutoencoderKL(
        in_channels=3, out_channels=3, latent_channels=4, block_out_channels=(16, 32), norm_num_groups=8,
        down_block_types=("DownEncoderBlock2D", "DownEncoderBlock2D"),
        up_block_types=("UpDecoderBlock2D", "UpDecoderBlock2D"), sample_size=32,
    ).save_pretrained(sd / "vae")
    CLIPTextModel(CLIPTextConfig(hidden_size=32, intermediate_size=37, num_attention_heads=4, num_hidden_layers=2,
                                 vocab_size=514, max_position_embeddings=16, bos_token_id=512, eos_token_id=513,
                                 pad_token_id=513)).save_pretrained(sd / "text_encoder")
    _write_byte_level_tokenizer(sd / "tokenizer")
    DDIMScheduler(num_train_timesteps=1000, beta_start=0.00085, beta_end=0.012, beta_schedule="scaled_linear",
                  clip_sample=False, set_alpha_to_one=False, steps_offset=1).save_pretrained(sd / "scheduler")
    (sd / "model_index.json").write_text(json.dumps({"_class_name": "StableDiffusionPipeline", "_tiny_random": True}))
    # VAE factor 2 (two encoder blocks) -> the adapter unshuffles by 2 to reach latent size.
    T2IAdapter(in_channels=3, channels=list(channels), num_res_blocks=1, downscale_factor=2,
               adapter_type="full_adapter").save_pretrained(adapter_dir)
    return sd, adapter_dir
