"""The rig: forward-facing, object orbit or inward shell, told apart from cameras and points; an inward
shell's near plane keeps a camera from drawing the splats of the wall it hangs on (issue 30 item 4)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from gsgs_engine.cameras import Camera, look_at
from gsgs_engine.effect_plan import (NEAR_FRACTION, SHELL_MIN_SHARE, apply_effect_plan, parse_overrides, plan_effects,
                                     rig_layout)
from gsgs_engine.io.scene import Scene, View
from gsgs_engine.priors.config import PriorConfig
from gsgs_engine.train.trainer import TrainConfig

SIZE = 24
DEFAULT_NEAR = TrainConfig().novel_view_near  # the renderer's own (0.01)
DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def camera(eye, target=(0.0, 0.0, 0.0), size=SIZE, name="") -> Camera:
    R, t = look_at(eye, target, up=(0.0, 0.0, 1.0))
    f = 0.5 * size / math.tan(math.radians(50) / 2)
    return Camera(R=R, t=t, fx=f, fy=f, cx=size / 2, cy=size / 2, width=size, height=size, name=name)


def sphere(n: int, radius: float, seed: int = 0) -> np.ndarray:
    """n points spread over a sphere (a Fibonacci lattice, tilted so no camera looks straight up)."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = i * math.pi * (3 - math.sqrt(5))
    r = np.sqrt(1 - z ** 2)
    pts = np.stack([r * np.cos(phi), r * np.sin(phi), 0.8 * z], 1)
    return radius * pts / np.linalg.norm(pts, axis=1, keepdims=True)


def shell_cameras(n: int = 9, radius: float = 2.75) -> list[Camera]:
    return [camera(p, name=f"s{i}") for i, p in enumerate(sphere(n, radius))]


def shell_points(radius: float = 2.75, seed: int = 0) -> np.ndarray:
    """A dome's content: people in the middle and the walls the cameras hang on (a share at the shell)."""
    rng = np.random.default_rng(seed)
    middle = rng.normal(0, 0.4, (150, 3))
    walls = sphere(100, 1.0) * rng.uniform(0.95 * radius, 1.15 * radius, (100, 1))
    return np.concatenate([middle, walls])


def orbit_points(seed: int = 0) -> np.ndarray:
    """An object in the middle of the orbit (NeRF-synthetic: everything within a third of the radius)."""
    return np.random.default_rng(seed).uniform(-0.7, 0.7, (300, 3))


def forward_cameras(n: int = 4) -> list[Camera]:
    return [camera((-0.5 + i / max(n - 1, 1), -4.0, 0.0), (-0.5 + i / max(n - 1, 1), 0.0, 0.0), name=f"f{i}")
            for i in range(n)]


# -- classification ---------------------------------------------------------------------------------
def test_an_inward_shell_is_told_from_an_orbit_by_where_its_points_lie():
    cams = shell_cameras()
    shell = rig_layout(cams, shell_points())
    assert shell["rig"] == "inward shell" and shell["points_at_shell"] >= SHELL_MIN_SHARE
    assert shell["shell_radius"] == pytest.approx(2.75, rel=1e-3)
    assert shell["near"] == pytest.approx(NEAR_FRACTION * 2.75, rel=1e-3)
    orbit = rig_layout(cams, orbit_points())  # the same cameras around an object
    assert orbit["rig"] == "object orbit" and orbit["near"] is None and orbit["points_at_shell"] < SHELL_MIN_SHARE
    # the near plane scales with the rig, whatever its units
    assert rig_layout(shell_cameras(radius=27.5), shell_points(27.5))["near"] == pytest.approx(10 * shell["near"])


def test_forward_facing_and_unmeasurable_rigs_keep_the_default_near_plane():
    fwd = rig_layout(forward_cameras(), shell_points())  # points at any distance: the axes never meet
    assert fwd["rig"] == "forward-facing" and fwd["near"] is None
    few = rig_layout(shell_cameras(), shell_points()[-10:])  # too few points to tell: an orbit, as before
    assert few["rig"] == "object orbit" and few["near"] is None and few["points"] == 10
    none = rig_layout(shell_cameras(), None)
    assert none["rig"] == "object orbit" and none["points"] == 0
    assert rig_layout(shell_cameras()[:1], shell_points())["near"] is None
    with_nan = np.concatenate([shell_points(), np.full((5, 3), np.nan)])  # non-finite points are ignored
    assert rig_layout(shell_cameras(), with_nan)["points"] == len(shell_points())


def test_rgb_photos_of_a_converging_rig_with_too_few_points_count_as_a_shell():
    # 3 of Panoptic's cameras (120 degrees apart) triangulate no point: RGB photos film their surroundings, so a
    # shell with its near plane; RGBA views (an object on nothing) stay an orbit; a forward rig stays forward
    few = rig_layout(shell_cameras(3), shell_points()[-10:], rgb=True)
    assert few["rig"] == "inward shell" and few["unmeasured"] and "points_at_shell" not in few
    assert few["near"] == pytest.approx(NEAR_FRACTION * few["shell_radius"])
    assert rig_layout(shell_cameras(3), None, rgb=False)["rig"] == "object orbit"
    assert rig_layout(forward_cameras(), None, rgb=True)["rig"] == "forward-facing"
    # measured points still decide: an RGB orbit whose points lie inside it stays an orbit
    assert rig_layout(shell_cameras(), orbit_points(), rgb=True)["rig"] == "object orbit"
    shell = _plan(_scene(shell_cameras(3), shell_points()[-10:]))
    assert shell["rig"].value == "inward shell" and "cannot measure" in shell["rig"].reason
    assert "rig=orbit" in shell["rig"].reason and shell["background"].value == "sphere"
    rgba = _plan(_scene(shell_cameras(3), shell_points()[-10:], alpha=True))
    assert rgba["rig"].value == "object orbit" and "RGBA" in rgba["rig"].reason


def _scene(cams, points, alpha: bool = False) -> Scene:
    img = np.full((SIZE, SIZE, 4 if alpha else 3), 0.5, np.float32)
    views = [View(camera=c, image_path=None, loader=lambda: img) for c in cams]
    return Scene(views=views, splits={"train": list(range(len(cams))), "test": []}, source="synthetic", format="test",
                 points=np.asarray(points, np.float32), point_colors=np.full((len(points), 3), 0.5, np.float32),
                 has_alpha=alpha)


def _plan(scene, overrides=None, prior="auto"):
    return plan_effects(scene, TrainConfig(init="points"), PriorConfig(prior=prior, num_pseudo=2, rounds=1),
                        {"sh_degree": 0, **(overrides or {})}, log=lambda m: None)


def test_the_plan_names_the_rig_and_sets_the_near_plane_only_for_a_shell():
    shell = _plan(_scene(shell_cameras(), shell_points()))
    assert shell["rig"].enabled and shell["rig"].value == "inward shell" and "near plane" in shell["rig"].reason
    assert "inward shell" in shell.format() and list(shell.to_dict())[0] == "rig"
    assert "inward-facing shell" in shell["pseudo_views"].reason
    tc, _ = apply_effect_plan(shell, TrainConfig(), PriorConfig(prior="auto"))
    assert tc.novel_view_near == pytest.approx(NEAR_FRACTION * 2.75, rel=1e-3)
    for prior in ("auto", "none"):  # the near plane is geometry, not a prior: plain 3DGS gets it too
        assert _plan(_scene(shell_cameras(), shell_points()), prior=prior)["rig"].enabled
    orbit = _plan(_scene(shell_cameras(), orbit_points()))
    assert not orbit["rig"].enabled and orbit["rig"].value == "object orbit"
    assert "orbiting" in orbit["pseudo_views"].reason
    assert apply_effect_plan(orbit, TrainConfig(), PriorConfig(prior="auto"))[0].novel_view_near == DEFAULT_NEAR
    fwd = _plan(_scene(forward_cameras(), shell_points()))
    assert fwd["rig"].value == "forward-facing" and not fwd["rig"].enabled
    assert apply_effect_plan(fwd, TrainConfig(), PriorConfig(prior="auto"))[0].novel_view_near == DEFAULT_NEAR


def test_the_rig_can_be_overridden():
    assert parse_overrides("rig=inward") == {"rig": "inward"}
    forced = _plan(_scene(shell_cameras(), orbit_points()), {"rig": "inward"})
    assert forced["rig"].enabled and forced["rig"].source == "user"
    assert apply_effect_plan(forced, TrainConfig(), None)[0].novel_view_near == pytest.approx(NEAR_FRACTION * 2.75,
                                                                                              rel=1e-3)
    off = _plan(_scene(shell_cameras(), shell_points()), {"rig": "orbit"})
    assert not off["rig"].enabled and apply_effect_plan(off, TrainConfig(), None)[0].novel_view_near == DEFAULT_NEAR
    from gsgs_engine import GsgsError

    with pytest.raises(GsgsError, match="rig=inward"):
        _plan(_scene(forward_cameras(), shell_points()), {"rig": "inward"})
    with pytest.raises(GsgsError, match="rig"):
        parse_overrides("rig=dome")


# -- the near plane in rendering and training ---------------------------------------------------------
def _splats(depths, dtype=torch.float32):
    n = len(depths)
    means = torch.tensor([[0.0, 0.0, float(d)] for d in depths], dtype=dtype, requires_grad=True)
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]] * n, dtype=dtype, requires_grad=True)
    scales = torch.full((n, 3), 0.05, dtype=dtype)
    scales[1:] = 0.5  # the scene: wide enough to cover the image's centre from 2 units
    scales.requires_grad_(True)
    opac = torch.full((n,), 0.95, dtype=dtype).requires_grad_(True)
    sh = torch.zeros(n, 1, 3, dtype=dtype)
    sh[0, 0] = torch.tensor([-1.7, -1.7, -1.7], dtype=dtype)  # the one at the lens: black
    sh[1:, 0] = torch.tensor([1.7, -1.7, -1.7], dtype=dtype)  # the scene: red
    return means, quats, scales, opac, sh.requires_grad_(True)


@pytest.mark.parametrize("backend", ["reference", "cpu"])
def test_a_splat_inside_the_near_plane_is_not_drawn_and_gradients_stay_finite(backend):
    from gsgs_engine.render import render

    cam = Camera(R=np.eye(3), t=np.zeros(3), fx=20.0, fy=20.0, cx=SIZE / 2, cy=SIZE / 2, width=SIZE, height=SIZE)
    leaves = _splats([0.05, 2.0])
    bg = torch.ones(3)
    try:
        blocked = render(*leaves, cam, 0, bg, backend=backend)
    except Exception as exc:  # the compiled CPU kernel may be unbuilt here
        pytest.skip(f"backend {backend} unavailable: {exc}")
    assert blocked.color[SIZE // 2, SIZE // 2].max() < 0.2  # the splat at the lens covers the centre
    out = render(*leaves, cam, 0, bg, backend=backend, near=0.275)
    centre = out.color[SIZE // 2, SIZE // 2]
    assert centre[0] > 0.8 and centre[1] < 0.2  # the scene behind it shows
    loss = out.color.sum()
    loss.backward()
    for leaf in leaves:
        assert leaf.grad is not None and torch.isfinite(leaf.grad).all()
    assert leaves[0].grad[0].abs().sum() == 0 and leaves[0].grad[1].abs().sum() > 0  # culled: no gradient


def test_the_trainer_draws_novel_views_with_the_near_plane_and_trains_with_the_default(monkeypatch):
    import gsgs_engine.render as render_module
    from gsgs_engine.train.trainer import Trainer, validate_config

    with pytest.raises(Exception, match="near"):
        validate_config(TrainConfig(novel_view_near=0.0))
    cams = shell_cameras(4)
    img = np.full((SIZE, SIZE, 3), 0.5, np.float32)
    views = [View(camera=c, image_path=None, loader=lambda: img) for c in cams]
    scene = Scene(views=views, splits={"train": [0, 1, 2], "test": [3]}, source="synthetic", format="test",
                  points=shell_points().astype(np.float32),
                  point_colors=np.full((250, 3), 0.5, np.float32))
    seen = []
    original = render_module.render

    def spy(*args, **kwargs):
        seen.append(kwargs.get("near"))
        return original(*args, **kwargs)

    monkeypatch.setattr(render_module, "render", spy)
    tr = Trainer(scene, TrainConfig(iters=2, init="points", sh_degree=0, backend="reference", novel_view_near=0.3,
                                    checkpoint_every=0), progress=None, log=lambda m: None)
    tr.setup()
    tr.train()
    assert seen and all(n is None for n in seen)  # training renders: the renderer's default
    assert torch.isfinite(tr.model.means).all()
    seen.clear()
    with torch.no_grad():
        out = tr.render(cams[3])
    assert torch.isfinite(out.color).all() and seen == [0.3]


# -- real data ------------------------------------------------------------------------------------
def _plan_of(path, **load):
    from gsgs_engine.io import load_scene

    if not path.is_dir():
        pytest.skip(f"{path} is absent (a checkout without ../shared/data)")
    scene = load_scene(path, **load)
    return plan_effects(scene, TrainConfig(), PriorConfig(prior="auto"), {}, log=lambda m: None)


@pytest.mark.slow
def test_real_rigs_are_classified_as_measured():
    """CMU Panoptic's dome is a shell; NeRF-synthetic's orbit and LLFF's row keep the default near plane."""
    pano = _plan_of(DATA / "panoptic_basketball", train_views=9, frames="0")
    assert pano["rig"].value == "inward shell" and pano["rig"].enabled
    assert json.loads(json.dumps(pano.to_dict()))["rig"]["measured"]["near"] > 0.01
    lego = _plan_of(DATA / "lego_200")
    assert lego["rig"].value == "object orbit" and not lego["rig"].enabled
    flower = _plan_of(DATA / "llff_flower", train_views=3)
    assert flower["rig"].value == "forward-facing" and not flower["rig"].enabled
