"""The diffusion prior's real code paths (load, LoRA eq. 6, DIFT features, generation) on tiny models.

The tiny models are randomly initialised instances of the real diffusers / transformers
classes: these tests check wiring and maths, not image quality (no pretrained weights here).
"""

import pytest
import torch

from gsgs_engine import GsgsError

pytest.importorskip("diffusers")
pytest.importorskip("peft")

from gsgs_engine.priors.diffusion import DiffusionPrior, DiffusionSettings  # noqa: E402
from gsgs_engine.priors.tiny_diffusion import save_tiny_diffusion  # noqa: E402


@pytest.fixture(scope="module")
def tiny_folders(tmp_path_factory):
    return save_tiny_diffusion(tmp_path_factory.mktemp("tiny_sd"))


def _prior(folders, **kw):
    sd, adapter = folders
    settings = DiffusionSettings(model_dir=str(sd), adapter_dir=str(adapter), resolution=32, steps=4, lora_steps=2,
                                 device="cpu", **kw)
    return DiffusionPrior(settings)


def _sample(h=24, w=30, seed=0):
    g = torch.Generator().manual_seed(seed)
    img = torch.rand(h, w, 3, generator=g)
    inv = torch.rand(h, w, generator=g) + 0.5
    return img, inv


def test_missing_folders_are_clear_errors(tmp_path):
    with pytest.raises(GsgsError, match="folder not found"):
        DiffusionPrior(DiffusionSettings(model_dir=str(tmp_path / "nope"), adapter_dir=str(tmp_path)))
    (tmp_path / "sd").mkdir()
    with pytest.raises(GsgsError, match="missing unet"):
        DiffusionPrior(DiffusionSettings(model_dir=str(tmp_path / "sd"), adapter_dir=str(tmp_path)))


@pytest.mark.slow
def test_only_lora_trains_and_eq6_terms_are_finite(tiny_folders):
    prior = _prior(tiny_folders)
    frozen = {n: p.detach().clone() for n, p in prior.unet.named_parameters() if not p.requires_grad}
    lora = {n: p.detach().clone() for n, p in prior.unet.named_parameters() if p.requires_grad}
    assert lora and all("lora" in n for n in lora)
    img, inv = _sample()
    warped, winv = _sample(seed=1)
    valid = torch.ones(24, 30, dtype=torch.bool)
    valid[:, :10] = False
    losses = prior.adapt([{"image": img, "inverse_depth": inv, "warped": warped, "warped_inverse_depth": winv,
                           "valid": valid}], steps=2)
    assert all(torch.isfinite(torch.tensor(v)) for v in losses.values())
    assert losses["geo"] > 0 and losses["ldm"] > 0 and losses["ldm_warped"] > 0
    after = dict(prior.unet.named_parameters())
    assert all(torch.equal(frozen[n], after[n]) for n in frozen)
    assert any(not torch.equal(lora[n], after[n]) for n in lora)


@pytest.mark.slow
def test_geometry_loss_vanishes_for_identical_views_and_not_otherwise(tiny_folders):
    prior = _prior(tiny_folders)
    img, inv = _sample()
    valid = torch.ones(24, 30, dtype=torch.bool)
    same = prior.geometry_loss(img, inv, img.clone(), inv.clone(), valid)
    other_img, other_inv = _sample(seed=5)
    diff = prior.geometry_loss(img, inv, other_img, other_inv, valid)
    assert same.item() == pytest.approx(0.0, abs=1e-6)
    assert diff.item() > 1e-4
    none_valid = prior.geometry_loss(img, inv, other_img, other_inv, torch.zeros(24, 30, dtype=torch.bool))
    assert none_valid.item() == 0.0


@pytest.mark.slow
def test_generation_is_deterministic_sized_and_lora_round_trips(tiny_folders, tmp_path):
    prior = _prior(tiny_folders)
    render, inv = _sample(20, 28)
    a = prior.generate(render, inv, seed=3)
    b = prior.generate(render, inv, seed=3)
    assert a.shape == (20, 28, 3) and torch.isfinite(a).all() and a.min() >= 0 and a.max() <= 1
    assert torch.equal(a, b)
    from_noise = prior.generate(render, inv, seed=3, strength=1.0)
    assert not torch.equal(a, from_noise)
    img, dinv = _sample()
    prior.adapt([{"image": img, "inverse_depth": dinv}], steps=1)
    adapted = prior.generate(render, inv, seed=3)
    prior.save_lora(tmp_path / "lora.safetensors")
    fresh = _prior(tiny_folders)
    fresh.load_lora(tmp_path / "lora.safetensors")
    assert torch.allclose(fresh.generate(render, inv, seed=3), adapted, atol=1e-5)


def test_depth_condition_is_normalised_and_safe_on_flat_maps(tiny_folders):
    prior = _prior(tiny_folders)
    flat = prior.depth_condition(torch.full((10, 12), 3.0), (16, 16))
    assert flat.shape == (1, 3, 16, 16) and torch.isfinite(flat).all() and flat.abs().max() == 0
    ramp = prior.depth_condition(torch.linspace(0, 5, 120).reshape(10, 12), (16, 16))
    assert ramp.min() >= 0 and ramp.max() <= 1 and ramp.max() > 0.9
