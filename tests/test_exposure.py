"""Per-camera exposure and white balance (train/techniques/exposure.py): the colour correction is exact on the
SH coefficients, novel views get none, the learned gains follow the photos' real gains, a pseudo view takes its
photo's camera, frames of one video camera share one correction, and a run resumes bit-identically with it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from gsgs_engine import GsgsError
from gsgs_engine.io.scene import Scene, View
from gsgs_engine.render.sh import eval_sh
from gsgs_engine.train.technique import PHOTO_VIEW, StepContext
from gsgs_engine.train.techniques.exposure import ExposureCompensation, camera_key, corrected_sh
from test_trainer import make_scene, make_trainer

GAINS = (0.75, 1.0, 1.3)  # what three "photos" were metered at, relative to the scene


def _metered_scene() -> Scene:
    """The tiny test scene with each training photo scaled by its own exposure (test views at 1.0)."""
    scene = make_scene(n_train=3, n_test=2)
    views = list(scene.views)
    for i, gain in enumerate(GAINS):
        img = views[i].image()
        views[i] = View(camera=views[i].camera, image_path=None,
                        loader=lambda img=img, gain=gain: np.clip(img * gain, 0.0, 1.0).astype(np.float32))
    return dataclasses.replace(scene, views=views)


@pytest.mark.parametrize("degree", [0, 1, 3])
def test_the_correction_is_an_affine_map_of_the_colour(degree):
    g = torch.Generator().manual_seed(0)
    sh = torch.randn(50, (degree + 1) ** 2, 3, generator=g) * 0.3
    dirs = torch.nn.functional.normalize(torch.randn(50, 3, generator=g), dim=-1)
    gain, offset = torch.tensor([0.8, 1.0, 1.25]), torch.tensor([0.05, -0.02, 0.0])
    before = eval_sh(degree, sh, dirs) + 0.5
    after = eval_sh(degree, corrected_sh(sh, gain, offset), dirs) + 0.5
    assert torch.allclose(after, gain * before + offset, atol=1e-5)


def test_training_renders_are_corrected_and_novel_views_are_not():
    trainer = make_trainer(iters=10, sh_degree=0)
    trainer.setup()
    exposure = ExposureCompensation()
    trainer.add_technique(exposure)
    with torch.no_grad():
        exposure.log_gain[1] = torch.log(torch.tensor([1.5, 1.5, 1.5]))
        exposure.log_gain[0] = -exposure.log_gain[1]
    cam = trainer.train_views[1].camera
    ctx = StepContext(trainer, 1, 1, None, trainer._targets[1], trainer.background)
    with torch.no_grad():
        plain = trainer.render(cam).color
        corrected = trainer.render_for_training(ctx, cam).color
        ctx.shared[PHOTO_VIEW] = 2  # e.g. a pseudo view warped from photo 2: that camera's correction (identity)
        other = trainer.render_for_training(ctx, cam).color
    assert not torch.allclose(corrected, plain, atol=1e-3)
    assert torch.allclose(other, plain, atol=1e-6)
    assert torch.equal(trainer.render(cam).color, plain)  # evaluation draws the model as it is


@pytest.mark.slow  # 150 steps of the tiny scene
def test_learned_gains_follow_the_photos_and_the_scene_keeps_the_average_colours():
    trainer = make_trainer(_metered_scene(), iters=150, sh_degree=0)
    trainer.setup()
    exposure = ExposureCompensation(lr=0.01)
    trainer.add_technique(exposure)
    trainer.train()
    gains = torch.exp(exposure.log_gain.detach()).mean(dim=1).numpy()
    assert np.all(np.diff(gains) > 0), gains  # ordered as the photos were metered
    ratio = gains[2] / gains[0]
    assert 1.3 < ratio < 2.2, gains  # the true ratio is 1.3 / 0.75 = 1.73
    assert abs(float(exposure.log_gain.detach().mean())) < 1e-6  # re-centred: the scene keeps the mean colours
    report = exposure.report()
    assert report["cameras"] == 3 and set(report["per_camera"]) == {"view 0", "view 1", "view 2"}


def test_frames_of_one_camera_share_a_correction():
    class _V:
        def __init__(self, extra):
            self.camera = type("C", (), {"extra": extra})()

    keys = [camera_key(_V({"camera_index": c, "frame": f}), i) for i, (c, f) in enumerate([(4, 0), (4, 1), (7, 0)])]
    assert keys[0] == keys[1] != keys[2]
    assert camera_key(_V({}), 5) == ("view", 5)


def test_one_camera_is_left_alone_and_bad_settings_are_refused():
    with pytest.raises(GsgsError, match="learning rate"):
        ExposureCompensation(lr=0.0)
    trainer = make_trainer(make_scene(n_train=1, n_test=1), iters=4, sh_degree=0)
    trainer.setup()
    exposure = ExposureCompensation()
    trainer.add_technique(exposure)
    trainer.train()
    assert torch.equal(exposure.log_gain, torch.zeros(1, 3))


def _run(tmp_path, until=None, resume=False):
    trainer = make_trainer(_metered_scene(), iters=30, sh_degree=0, checkpoint_every=15, tmp_path=tmp_path)
    trainer.setup(resume=resume)
    trainer.add_technique(ExposureCompensation(lr=0.01))
    trainer.train(until=until)
    return trainer


def test_resume_with_exposure_is_bit_identical(tmp_path):
    straight = _run(tmp_path / "a")
    _run(tmp_path / "b", until=15)
    resumed = _run(tmp_path / "b", resume=True)
    for name, p in straight.model.params.items():
        assert torch.equal(p, resumed.model.params[name]), name
    assert straight.techniques[0].report() == resumed.techniques[0].report()
