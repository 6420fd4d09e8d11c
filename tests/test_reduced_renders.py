"""Renders at a reduced resolution (issue 29): pseudo views and the binocular shifted view rendered
smaller, and the coarse-to-fine schedule of the training view. Each keeps its targets, masks and
gradients consistent with the smaller render, and a scale of 1 changes nothing."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from gsgs_engine import GsgsError
from gsgs_engine.train.technique import StepContext
from test_trainer import make_trainer


def test_resize_area_keeps_the_mean_and_is_a_no_op_at_the_same_size():
    from gsgs_engine.train.resample import resize_area

    img = torch.rand(30, 40, 3, generator=torch.Generator().manual_seed(0))
    half = resize_area(img, 15, 20)
    assert half.shape == (15, 20, 3)
    assert torch.allclose(half[0, 0], img[:2, :2].reshape(-1, 3).mean(0), atol=1e-6)  # exact 2x2 blocks
    assert half.mean().item() == pytest.approx(img.mean().item(), rel=1e-5)
    assert resize_area(img, 30, 40) is img
    mask = torch.zeros(30, 40)
    mask[:, :20] = 1.0
    small = resize_area(mask, 15, 20)
    assert small.shape == (15, 20) and small[:, :10].eq(1).all() and small[:, 10:].eq(0).all()


def _pseudo_views(trainer, with_mask: bool):
    from gsgs_engine.train.techniques.pseudo_views import PseudoView

    views = []
    for i, v in enumerate(trainer.train_views):
        mask = np.ones((v.camera.height, v.camera.width), np.float32)
        mask[:, : v.camera.width // 2] = 0.0
        views.append(PseudoView(v.camera, trainer._targets[i].numpy(), weight=0.5, name=f"p{i}",
                                mask=mask if with_mask else None))
    return views


@pytest.mark.parametrize("with_mask", [False, True])
def test_pseudo_views_render_at_their_scale_with_area_averaged_targets(with_mask):
    from gsgs_engine.train.techniques.pseudo_views import PseudoSupervision

    trainer = make_trainer(iters=10)
    trainer.setup()
    sup = trainer.add_technique(PseudoSupervision(_pseudo_views(trainer, with_mask), scale=0.5))
    full = trainer.train_views[0].camera
    ctx = StepContext(trainer, 3, 0, None, trainer._targets[0], trainer.background)
    terms = sup.loss_terms(ctx)
    out, camera = ctx.renders[-1]
    assert (camera.width, camera.height) == (full.width // 2, full.height // 2)
    assert tuple(out.color.shape) == (full.height // 2, full.width // 2, 3)
    assert all(t.shape[:2] == (full.height // 2, full.width // 2) for t in sup._targets)
    if with_mask:
        assert sup._masks[0].shape == (full.height // 2, full.width // 2) and sup._masks[0][:, 0].eq(0).all()
    loss = sum(w * v for w, v in terms.values())
    assert torch.isfinite(loss)
    loss.backward()
    assert trainer.model.params["means"].grad.abs().sum() > 0
    assert sup.report()["scale"] == 0.5
    with pytest.raises(GsgsError, match="render scale"):
        PseudoSupervision(scale=0.0)
    with pytest.raises(GsgsError, match="render scale"):
        PseudoSupervision(scale=1.5)


def test_binocular_scale_is_checked():
    from gsgs_engine.train.techniques.binocular import BinocularConsistency

    for bad in (0.0, -1.0, 1.5):
        with pytest.raises(GsgsError, match="render scale"):
            BinocularConsistency(scale=bad)


def test_binocular_every_k_steps_renders_the_shifted_view_on_those_steps_only():
    from gsgs_engine.train.techniques.binocular import BinocularConsistency
    from gsgs_engine.train.techniques.catalogue import make_techniques, parse_techniques

    trainer = make_trainer(iters=9)
    trainer.setup()
    bino = trainer.add_technique(make_techniques(parse_techniques("binocular:every=3:start_fraction=0"))[0])
    trainer.train()
    assert bino.start == 1 and bino.steps == 3  # steps 1, 4 and 7
    assert bino.report()["every"] == 3 and trainer.nan_steps_skipped == 0
    for bad in (0, -2, 1.5, "2"):
        with pytest.raises(GsgsError, match="every must be a whole number"):
            BinocularConsistency(every=bad)


def test_coarse_to_fine_renders_the_first_steps_smaller_then_full_size():
    trainer = make_trainer(iters=8, densify=True, coarse_fraction=0.5, coarse_scale=0.5)
    trainer.setup()
    full = trainer.train_views[0].camera
    sizes = []
    for _ in range(8):
        assert trainer.train_step()
        out, camera = trainer.last_step_renders[0]
        assert tuple(out.color.shape[:2]) == (camera.height, camera.width)
        sizes.append(camera.width)
    assert sizes == [full.width // 2] * 4 + [full.width] * 4
    assert [trainer.step_scale(s) for s in (1, 4, 5, 8)] == [0.5, 0.5, 1.0, 1.0]
    # the reduced photos are made once per view and are the area average of the full ones
    from gsgs_engine.train.resample import resize_area

    for (i, w, h), small in trainer._reduced_targets.items():
        assert torch.equal(small, resize_area(trainer._targets[i], h, w))
    assert trainer.nan_steps_skipped == 0


def test_coarse_to_fine_off_by_default_and_checked():
    from gsgs_engine.train.trainer import TrainConfig, validate_config

    trainer = make_trainer(iters=4)
    trainer.setup()
    assert all(trainer.step_scale(s) == 1.0 for s in range(1, 5))
    for bad in ({"coarse_fraction": 1.5}, {"coarse_fraction": -0.1}, {"coarse_scale": 0.0}, {"coarse_scale": 2.0}):
        with pytest.raises(GsgsError, match="coarse_"):
            validate_config(TrainConfig(**bad))


def test_technique_and_kernel_seconds_are_recorded():
    trainer = make_trainer(iters=3)
    trainer.setup()
    from gsgs_engine.train.techniques.dropout import GaussianDropout

    trainer.add_technique(GaussianDropout())
    trainer.train()
    assert set(trainer.technique_seconds) == {"dropout"} and trainer.technique_seconds["dropout"] >= 0
    kernel = trainer.kernel_seconds()
    if trainer.backend_used == "cpu":
        assert kernel is not None and kernel["raster_forward"] > 0 and kernel["raster_backward"] > 0
