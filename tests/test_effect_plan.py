"""The effect plan: each effect decided from the data (static/dynamic, RGBA/RGB, depth source, dense/sparse,
weights), overridable, and a disabled effect costs nothing (calls counted, not time)."""

from __future__ import annotations

import functools
import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera
from gsgs_engine.effect_plan import DENSE_MAX_GAP_DEG, apply_effect_plan, coverage, exposure_corrected_spread, identifiable_sh_degree, measure_view_dependence, parse_overrides, plan_effects, sh_degree_for_spread, shared_triangulation
from gsgs_engine.io.scene import Scene, View
from gsgs_engine.priors.config import PriorConfig
from gsgs_engine.train.trainer import TrainConfig

SIZE = 16


def look_at(eye, size=SIZE, name="", direction=None) -> Camera:
    eye = np.asarray(eye, dtype=np.float64)
    f = -eye if direction is None else np.asarray(direction, dtype=np.float64)
    f = f / np.linalg.norm(f)
    r = np.cross(f, [0.0, 0.0, 1.0])
    r /= np.linalg.norm(r)
    R = np.stack([r, np.cross(f, r), f])
    focal = 0.5 * size / math.tan(math.radians(50) / 2)
    return Camera(R=R, t=-R @ eye, fx=focal, fy=focal, cx=size / 2, cy=size / 2, width=size, height=size, name=name)


def ring(n: int, span_deg: float = 360.0, offset: float = 0.0, prefix="v") -> list[Camera]:
    step = math.radians(span_deg) / (n if span_deg >= 360 else max(n - 1, 1))
    return [look_at((4 * math.cos(offset + i * step), 4 * math.sin(offset + i * step), 1.0), name=f"{prefix}{i}")
            for i in range(n)]


def row(n: int, offset: float = 0.0, prefix="v") -> list[Camera]:
    """A forward-facing rig: cameras side by side, parallel optical axes, all seeing the origin."""
    return [look_at((-0.6 + 1.2 * (i + offset) / max(n - 1, 1), -4.0, 1.0), name=f"{prefix}{i}",
                    direction=(0.0, 1.0, -0.25)) for i in range(n)]


@functools.lru_cache(maxsize=None)
def _renders(n_train: int, span_deg: float, n_test: int, forward: bool = False):
    """Cameras, RGBA renders of a dozen Gaussians, and sparse points (cached: tests reuse scenes)."""
    from gsgs_engine.render import render

    g = torch.Generator().manual_seed(0)
    n = 12
    gt = ((torch.rand(n, 3, generator=g) - 0.5), torch.randn(n, 4, generator=g),
          torch.rand(n, 3, generator=g) * 0.2 + 0.1, torch.full((n,), 0.9),
          (torch.rand(n, 1, 3, generator=g) - 0.5) / 0.28)
    cams = (row(n_train) + row(n_test, offset=0.5, prefix="t") if forward else
            ring(n_train, span_deg) + ring(n_test, offset=0.3, prefix="t"))
    images = []
    for cam in cams:
        with torch.no_grad():
            out = render(*gt, cam, 0, torch.ones(3), backend="reference")
        images.append(np.concatenate([out.color.numpy(), out.alpha.numpy()[..., None]], -1).astype(np.float32))
    pts = np.concatenate([gt[0].numpy()] * 10) + np.random.default_rng(0).normal(0, 0.02, (10 * n, 3))
    return cams, images, pts.astype(np.float32)


def make_scene(n_train=4, span_deg=360.0, rgba=False, times=None, n_test=1, forward=False) -> Scene:
    cams, images, pts = _renders(n_train, span_deg, n_test, forward)
    if times is not None:
        cams = [replace(c, time=t) for c, t in zip(cams, times + [times[0]] * n_test)]
    views = [View(camera=cam, image_path=None, loader=lambda img=img if rgba else img[..., :3]: img)
             for cam, img in zip(cams, images)]
    return Scene(views=views, splits={"train": list(range(n_train)), "test": list(range(n_train, len(views)))},
                 source="synthetic", format="test", points=pts.copy(),
                 point_colors=np.full((len(pts), 3), 0.5, np.float32), has_alpha=rgba)


def fake_triangulation(num_points: int):
    return SimpleNamespace(points=np.zeros((num_points, 3), np.float32), colors=np.zeros((num_points, 3), np.float32),
                           tracks=[], errors=np.zeros(num_points))


AUTO = PriorConfig(prior="auto", num_pseudo=2, rounds=1)
SH1 = {"sh_degree": 1}  # pin SH where a test is about something else (no triangulation needed)


def plan(scene, prior=AUTO, overrides=None, tri=None, **cfg):
    return plan_effects(scene, TrainConfig(init="points", **cfg), prior, {**SH1, **(overrides or {})},
                        triangulation=tri, log=lambda m: None)


# -- decisions --------------------------------------------------------------------------------------------
def video_scene(n_cameras: int, n_frames: int, rgba: bool = True) -> Scene:
    """n_cameras that do not move, each filming n_frames times (a synchronised rig's training views)."""
    cams, images, pts = _renders(n_cameras, 360.0, 1)
    views = []
    for f in range(n_frames):
        for cam, img in zip(cams[:n_cameras], images):
            views.append(View(camera=replace(cam, time=f / max(n_frames - 1, 1)), image_path=None,
                              loader=lambda img=img if rgba else img[..., :3]: img))
    test = View(camera=replace(cams[-1], time=0.0), image_path=None, loader=lambda: images[-1])
    return Scene(views=views + [test], splits={"train": list(range(len(views))), "test": [len(views)]},
                 source="synthetic", format="test", points=pts.copy(),
                 point_colors=np.full((len(pts), 3), 0.5, np.float32), has_alpha=rgba)


def test_a_videos_cameras_count_once_as_viewpoints():
    from gsgs_engine.effect_plan import viewpoints

    scene = video_scene(3, 10)
    cams = [scene.views[i].camera for i in scene.splits["train"]]
    assert len(cams) == 30 and [c.name for c in viewpoints(cams)] == [c.name for c in cams[:3]]
    moved = replace(cams[0], t=np.asarray(cams[0].t) + 0.1)  # a camera that moved is another viewpoint
    assert len(viewpoints(cams + [moved])) == 4
    p = plan_effects(scene, TrainConfig(init="points"), AUTO, {}, log=lambda m: None)
    # 3 viewpoints identify degree 0 (30 views would say 3), and the rig is as sparse as its 3 cameras
    assert p["sh_degree"].measured["identifiable_degree"] == 0 and p["sh_degree"].measured["viewpoints"] == 3
    assert p["pseudo_views"].measured["views"] == 3 and "3 views (< " in p["pseudo_views"].reason
    assert p["time"].enabled


def test_static_vs_dynamic():
    static = plan(make_scene())
    assert static["time"].enabled is False and static["time"].value == "static"
    dynamic = plan(make_scene(times=[0.0, 0.3, 0.6, 1.0]))
    assert dynamic["time"].enabled and dynamic["time"].measured["distinct_times"] == 4
    from gsgs_engine.effect_plan import scene_for_plan
    from gsgs_engine.train.dynamic import SpacetimeTrainer, make_trainer

    timed = make_scene(times=[0.0, 0.3, 0.6, 1.0])
    kept = scene_for_plan(timed, dynamic)  # the trainer builds the 4D model for it: the times stay
    assert kept.has_time and [v.camera.time for v in kept.views] == [v.camera.time for v in timed.views]
    assert scene_for_plan(timed, plan(timed, overrides={"background": "fixed"})) is timed  # nothing to change
    off = plan(timed, overrides={"time": "off"})
    assert off["time"].enabled is False and off["time"].source == "user"
    flat = scene_for_plan(timed, off)
    assert flat.has_time is False and timed.has_time  # the input scene is untouched
    # a static plan never allocates temporal parameters: the plain 3D trainer
    assert not isinstance(make_trainer(flat, TrainConfig(iters=1, backend="reference")), SpacetimeTrainer)
    assert isinstance(make_trainer(timed, TrainConfig(iters=1, backend="reference")), SpacetimeTrainer)
    assert scene_for_plan(make_scene(), static).has_time is False
    with pytest.raises(GsgsError, match="distinct frame times"):
        plan(make_scene(), overrides={"time": "on"})


def test_rgba_vs_rgb_background():
    from gsgs_engine.effect_plan import scene_for_plan

    rgba, orbit = plan(make_scene(rgba=True)), plan(make_scene(rgba=False))
    rgb = plan(make_scene(rgba=False), overrides={"rig": "inward"})
    plain = plan(make_scene(rgba=False), PriorConfig(prior="none"), overrides={"rig": "inward"})
    # RGBA: alpha learned. An inward shell's RGB photos under the weights-free recipe: a texture learned on the
    # sphere through the cameras, starting from their mean colour, is the background (what a novel view shows where
    # no splat covers it); other rigs and plain 3DGS keep the fixed one
    assert rgba["background"].value == "transparent" and rgb["background"].value == "sphere"
    assert apply_effect_plan(rgb, TrainConfig(), AUTO)[0].background_sphere == 256
    assert orbit["background"].value == "fixed" and "horns" in orbit["background"].reason
    assert plain["background"].value == "fixed" and plain["background"].enabled is False
    video = plan(make_scene(times=[0.0, 0.5, 1.0]), overrides={"rig": "inward"})  # the 4D model: the same
    assert video["time"].enabled and video["background"].value == "sphere"
    rgb_scene = make_scene(rgba=False)
    photos = np.stack([v.image() for v in rgb_scene.train])
    want = photos.reshape(len(photos), -1, 3).mean(axis=1).mean(axis=0)
    colour = rgb["background"].measured["colour"]
    assert np.allclose(colour, want, atol=1e-4) and not np.allclose(colour, 1.0)
    trained_on = scene_for_plan(rgb_scene, rgb)
    assert np.allclose(trained_on.background, colour) and np.allclose(rgb_scene.background, 1.0)  # input untouched
    assert np.allclose(scene_for_plan(rgb_scene, plain).background, 1.0)
    assert apply_effect_plan(rgba, TrainConfig(), AUTO)[0].random_background is True
    assert apply_effect_plan(rgb, TrainConfig(random_background=True), AUTO)[0].random_background is False
    opaque = plan(make_scene(), overrides={"background": "opaque"})
    assert opaque["background"].value == "opaque" and opaque["background"].enabled
    assert apply_effect_plan(opaque, TrainConfig(), AUTO)[0].random_background is True
    assert np.allclose(scene_for_plan(rgb_scene, opaque).background, 1.0)
    asked = plan(make_scene(), PriorConfig(prior="none"), overrides={"background": "mean"})
    assert asked["background"].value == "mean" and asked["background"].source == "user"
    assert np.allclose(asked["background"].measured["colour"], colour)
    assert plan(make_scene(rgba=True), overrides={"background": "fixed"})["background"].value == "fixed"
    assert plan(make_scene(), overrides={"background": "fixed"})["background"].value == "fixed"
    # --random-background / the job setting: whichever random background the views allow
    assert plan(make_scene(rgba=True), overrides={"background": "random"})["background"].value == "transparent"
    assert plan(make_scene(), PriorConfig(prior="none"), overrides={"background": "random"})["background"].value == \
        "opaque"
    with pytest.raises(GsgsError, match="no alpha.*opaque"):
        plan(make_scene(), overrides={"background": "transparent"})
    for value in ("opaque", "mean", "sphere"):
        with pytest.raises(GsgsError, match="has an alpha channel"):
            plan(make_scene(rgba=True), overrides={"background": value})


def test_with_and_without_a_depth_source(tmp_path):
    scene = make_scene(forward=True)
    scene.points = None
    with_points = plan(scene, replace(AUTO, depth_source="sparse"), tri=fake_triangulation(200))
    assert with_points["depth"].value == "sparse" and with_points["depth"].measured["sfm_points"] == 200
    unasked = plan(scene, tri=fake_triangulation(200))  # auto: SfM-point depth measured to hurt, so off
    assert unasked["depth"].enabled is False and "measured" in unasked["depth"].reason
    assert plan(scene, overrides={"depth": "on"}, tri=fake_triangulation(200))["depth"].value == "sparse"
    assert plan(scene, replace(AUTO, prior="depth"), tri=fake_triangulation(200))["depth"].value == "sparse"
    few = plan(scene, tri=fake_triangulation(10))
    assert few["depth"].enabled is False and "10 SfM points" in few["depth"].reason
    (tmp_path / "dpt").mkdir()
    model = plan(scene, replace(AUTO, depth_source=str(tmp_path / "dpt")), tri=fake_triangulation(0))
    assert model["depth"].value == str(tmp_path / "dpt")
    assert plan(scene, replace(AUTO, prior="none"), tri=fake_triangulation(200))["depth"].enabled is False
    assert plan(scene, replace(AUTO, depth_reg=False), tri=fake_triangulation(200))["depth"].enabled is False
    with pytest.raises(GsgsError, match="no depth source"):
        plan(scene, overrides={"depth": "on"}, tri=fake_triangulation(10))
    with pytest.raises(GsgsError, match="--prior depth: no depth source"):  # never plain 3DGS in disguise
        plan(scene, replace(AUTO, prior="depth"), tri=fake_triangulation(10))
    _, pc = apply_effect_plan(few, TrainConfig(), AUTO)
    assert (pc.depth_reg, pc.depth_source, pc.prior) == (False, "none", "warp")


def test_an_explicit_dense_init_still_measures_points_for_depth_and_sh(monkeypatch):
    # `--init mvs` once skipped the plan's triangulation: --prior depth then trained plain 3DGS ("0 SfM
    # points") and the SH degree fell back to the views' cap instead of the measured spread
    import gsgs_engine.sfm as sfm

    calls = []
    monkeypatch.setattr(sfm, "triangulate_with_known_poses", lambda views: calls.append(len(views)) or
                        fake_triangulation(200))
    scene = make_scene(forward=True)
    scene.points = None
    for init in ("mvs", "sfm", "auto"):
        p = plan_effects(scene, TrainConfig(init=init), replace(AUTO, prior="depth"), {}, log=lambda m: None)
        assert p["depth"].value == "sparse" and p["depth"].measured["sfm_points"] == 200
        assert p.triangulation is not None  # shared with the init (the stereo's depth ranges)
    assert calls == [4, 4, 4]
    given = make_scene(forward=True)  # with the source's own points
    p = plan_effects(given, TrainConfig(init="points"), replace(AUTO, prior="depth"), {}, log=lambda m: None)
    assert p.triangulation is None and calls == [4, 4, 4]  # init from the given points: nothing triangulated


def test_dense_vs_sparse_views():
    dense = make_scene(n_train=24)  # a full ring: neighbours 15 deg apart (seen from the centre)
    cov = coverage([v.camera for v in dense.train])
    assert cov["nn_gap_median_deg"] < DENSE_MAX_GAP_DEG and cov["focus"] == "optical axes intersection"
    p = plan(dense)
    assert p["pseudo_views"].enabled is False and p["generator"].enabled is False
    assert "dense" in p["pseudo_views"].reason
    tc, pc = apply_effect_plan(p, TrainConfig(), AUTO)
    assert pc.prior in ("depth", "none")
    few = plan(make_scene(n_train=4, forward=True))
    assert few["pseudo_views"].value == 2 and few["generator"].value == "warp-inpaint" and "4 views" in \
        few["pseudo_views"].reason
    orbit = plan(make_scene(n_train=4))  # a sparse orbit: warp-inpaint measured to hurt there, so no pseudo views
    assert orbit["pseudo_views"].enabled is False and "orbiting" in orbit["pseudo_views"].reason
    assert orbit["generator"].enabled is False and orbit["techniques"].enabled
    holes = plan(make_scene(n_train=14))  # enough views, but 25.7 deg apart
    assert "gap" in holes["pseudo_views"].reason and holes["techniques"].enabled
    assert plan(dense, overrides={"pseudo_views": 3})["pseudo_views"].value == 3
    assert plan(make_scene(n_train=4), overrides={"pseudo_views": "off"})["pseudo_views"].enabled is False
    assert plan(dense, replace(AUTO, prior="warp"))["pseudo_views"].enabled  # an explicit request wins


def test_techniques_under_auto_on_sparse_static_views_and_as_named_otherwise():
    from gsgs_engine.effect_plan import AUTO_TECHNIQUES

    from gsgs_engine.effect_plan import AUTO_ORBIT_TECHNIQUES

    few = plan(make_scene(n_train=4))  # an object orbit: the shifted view every second step
    assert few["rig"].value == "object orbit" and few["techniques"].value == list(AUTO_ORBIT_TECHNIQUES)
    assert few["techniques"].source == "auto" and "sparse" in few["techniques"].reason
    assert "every second step" in few["techniques"].reason
    assert "dropout:max_rate=0.1" in AUTO_ORBIT_TECHNIQUES and "rate 0.1" in few["techniques"].reason  # session 23
    assert AUTO_ORBIT_TECHNIQUES[0] == "clone_split" and "clone / split" in few["techniques"].reason  # session 38
    assert AUTO_ORBIT_TECHNIQUES[-1] == "distortion" and "depth distortion" in few["techniques"].reason  # session 47
    tc, pc = apply_effect_plan(few, TrainConfig(), AUTO)
    assert pc.techniques == list(AUTO_ORBIT_TECHNIQUES)
    # a long schedule (the best preset's 3000 steps): the shifted view at every step again, recorded as such
    from gsgs_engine.effect_plan import AUTO_LONG_STEPS, AUTO_ORBIT_LONG_TECHNIQUES

    # (the views triangulate: these 16 px RGB ones give no point, which reads a shell, so the orbit is RGBA here)
    long_run = plan_effects(make_scene(n_train=4, rgba=True), TrainConfig(iters=AUTO_LONG_STEPS), AUTO, SH1,
                            log=lambda m: None)
    assert long_run["techniques"].value == list(AUTO_ORBIT_LONG_TECHNIQUES) and "binocular" in AUTO_ORBIT_LONG_TECHNIQUES
    assert AUTO_ORBIT_LONG_TECHNIQUES[0] == "clone_split" and "clone / split" in long_run["techniques"].reason  # s39
    assert "every step" in long_run["techniques"].reason
    assert plan_effects(make_scene(n_train=4, rgba=True), TrainConfig(iters=AUTO_LONG_STEPS - 1), AUTO, SH1,
                        log=lambda m: None)["techniques"].value == list(AUTO_ORBIT_TECHNIQUES)
    shell = plan(make_scene(n_train=4), overrides={"rig": "inward"})  # a shell: the base recipe (not measured there)
    assert shell["techniques"].value == list(AUTO_TECHNIQUES)
    assert plan(make_scene(n_train=24))["techniques"].enabled is False  # dense: plain optimisation
    # a forward-facing rig: the same recipe with density-guided dropout (measured on LLFF), recorded as such
    from gsgs_engine.effect_plan import AUTO_FORWARD_TECHNIQUES

    front = plan(make_scene(n_train=4, forward=True))
    assert front["rig"].value == "forward-facing" and front["techniques"].value == list(AUTO_FORWARD_TECHNIQUES)
    assert "density-guided" in front["techniques"].reason
    for recipe in (AUTO_FORWARD_TECHNIQUES, AUTO_ORBIT_TECHNIQUES):  # the same techniques, options changed, and
        assert [t.split(":")[0] for t in recipe if not t.startswith(("absgrad", "clone_split", "distortion"))] == list(
            AUTO_TECHNIQUES)  # AbsGS's, the clone / split boundary's and the depth distortion's
    assert AUTO_FORWARD_TECHNIQUES[0] == "absgrad" and "absolute gradients" in front["techniques"].reason  # session 29
    assert apply_effect_plan(front, TrainConfig(), AUTO)[1].techniques == list(AUTO_FORWARD_TECHNIQUES)
    assert "binocular:scale=0.5" in AUTO_FORWARD_TECHNIQUES  # the shifted view at half size (measured at 1000 steps)
    from gsgs_engine.effect_plan import AUTO_FORWARD_LONG_TECHNIQUES

    front_long = plan_effects(make_scene(n_train=4, forward=True), TrainConfig(iters=AUTO_LONG_STEPS), AUTO, SH1,
                              log=lambda m: None)["techniques"]  # a long schedule: the full-size view it was measured with
    assert front_long.value == list(AUTO_FORWARD_LONG_TECHNIQUES) and "binocular" in AUTO_FORWARD_LONG_TECHNIQUES
    assert "full size" in front_long.reason
    # ... densified by absolute gradients, as the 1000-step recipe (sessions 41-42)
    assert AUTO_FORWARD_LONG_TECHNIQUES[0] == "absgrad" and "absolute gradients" in front_long.reason
    assert plan(make_scene(n_train=4), replace(AUTO, prior="none"))["techniques"].value == []  # the baseline stays plain
    video = plan_effects(make_scene(times=[0.0, 0.3, 0.6, 1.0]), TrainConfig(), AUTO, SH1, log=lambda m: None)
    # the 4D recipe: one camera a frame here, so the few-camera one (dropout and opacity decay too)
    assert video["techniques"].value == ["dropout", "opacity_decay", "exposure"]
    assert "4D" in video["techniques"].reason and video["techniques"].measured["cameras_per_frame"] == 1
    rig = plan_effects(make_scene(n_train=16, times=[0.0] * 8 + [1.0] * 8), TrainConfig(), AUTO, SH1,
                       log=lambda m: None)  # 8 cameras filming 2 moments
    assert rig["techniques"].value == ["exposure"] and rig["techniques"].measured["cameras_per_frame"] == 8
    from gsgs_engine.train.techniques.catalogue import parse_techniques

    assert [t["name"] for t in parse_techniques(video["techniques"].value, "x")] == video["techniques"].value
    assert video["init"].value == "mvs" and "per frame" in video["init"].reason
    assert plan(make_scene(times=[0.0, 0.3, 0.6, 1.0]), replace(AUTO, prior="none"))["techniques"].value == []
    named = plan(make_scene(n_train=24), replace(AUTO, prior="none", techniques=["dropout"]))["techniques"]
    assert named.enabled and named.value == ["dropout"] and named.source == "user"
    off = plan(make_scene(n_train=4), replace(AUTO, techniques=[]))["techniques"]  # --techniques none
    assert off.enabled is False and off.source == "user"
    assert "techniques" in few.format()
    # the recipe starts from the dense MVS initialisation, unless an init was chosen
    assert few["init"].value == "points" and few["init"].source == "user"  # plan() chooses init="points"
    chosen = plan_effects(make_scene(n_train=4), TrainConfig(init="random"), AUTO, SH1, log=lambda m: None)
    assert chosen["init"].value == "random" and chosen["init"].source == "user"
    auto_init = plan_effects(make_scene(n_train=4), TrainConfig(), AUTO, SH1, log=lambda m: None)
    assert auto_init["init"].value == "mvs" and auto_init["init"].source == "auto"
    assert apply_effect_plan(auto_init, TrainConfig(), AUTO)[0].init == "mvs"
    assert plan_effects(make_scene(n_train=4), TrainConfig(), replace(AUTO, prior="none"), SH1,
                        log=lambda m: None)["init"].value == "auto"
    # naming the techniques (one option changed) under --prior auto keeps the dense init; none of them drops it
    tuned = plan_effects(make_scene(n_train=4), TrainConfig(), replace(AUTO, techniques=["dropout:max_rate=0.1"]), SH1,
                         log=lambda m: None)
    assert tuned["techniques"].source == "user" and tuned["init"].value == "mvs"
    assert plan_effects(make_scene(n_train=4), TrainConfig(), replace(AUTO, techniques=[]), SH1,
                        log=lambda m: None)["init"].value == "auto"


def test_generator_is_diffusion_only_with_weights(tmp_path):
    scene = make_scene(n_train=4, forward=True)
    with pytest.raises(GsgsError, match="--diffusion-model"):
        plan(scene, overrides={"generator": "diffusion"})
    (tmp_path / "sd").mkdir()
    (tmp_path / "ad").mkdir()
    weights = replace(AUTO, diffusion_model=str(tmp_path / "sd"), depth_adapter=str(tmp_path / "ad"))
    p = plan(scene, weights)
    assert p["generator"].value == "diffusion"
    assert apply_effect_plan(p, TrainConfig(), weights)[1].prior == "diffusion"
    assert plan(scene, weights, overrides={"generator": "warp"})["generator"].value == "warp-inpaint"


def test_overrides_parse_and_reject_unknown_names():
    assert parse_overrides("sh_degree=1, pseudo_views=off,depth=on") == {"sh_degree": 1, "pseudo_views": "off",
                                                                         "depth": "on"}
    for bad, match in (("colour=1", "unknown effect"), ("sh_degree=5", "sh_degree"), ("sh_degree", "NAME=VALUE"),
                       ("pseudo_views=-2", "positive")):
        with pytest.raises(GsgsError, match=match):
            parse_overrides(bad)


# -- view-dependent colour ---------------------------------------------------------------------------------
def test_exposure_is_removed_before_measuring_spread():
    rng = np.random.default_rng(0)
    albedo = rng.uniform(0.2, 0.8, (200, 3))
    gains = np.array([[1.0, 1.0, 1.0], [1.3, 1.2, 1.1], [0.8, 0.9, 0.85], [1.1, 1.0, 0.9]])
    obs = [np.column_stack([np.arange(4), albedo[p] * gains]) for p in range(200)]
    m = exposure_corrected_spread(obs, 4)
    assert m["spread_median"] < 1e-6
    np.testing.assert_allclose(np.asarray(m["gains"]) / np.asarray(m["gains"])[0], gains / gains[0], rtol=1e-3)
    shiny = [np.column_stack([np.arange(4), albedo[p] * gains + rng.normal(0, 0.1, (4, 3))]) for p in range(200)]
    assert exposure_corrected_spread(shiny, 4)["spread_median"] > 0.07
    assert [sh_degree_for_spread(s) for s in (0.0, 0.03, 0.05, 0.2)] == [0, 1, 2, 3]
    assert [identifiable_sh_degree(n) for n in (1, 3, 4, 8, 9, 15, 16, 100)] == [0, 0, 1, 1, 2, 2, 3, 3]


def _patch_views(n_views: int, n_pts: int, shiny_points, seed: int = 1):
    """Images of n_pts square patches seen by n_views views (each view puts every point in a different cell of a
    7 x 7 grid) and their tracks: a point in `shiny_points` changes colour from view to view (noise 0.12), the others
    keep it up to a per-view gain (exposure)."""
    rng = np.random.default_rng(seed)
    size = 84  # a 7 x 7 grid of 12-px cells
    images = [np.zeros((size, size, 3), np.float32) for _ in range(n_views)]
    cells = [rng.permutation(49)[:n_pts] for _ in range(n_views)]
    tracks = []
    for p in range(n_pts):
        base = rng.uniform(0.3, 0.7, 3)
        track = []
        for v in range(n_views):
            y, x = divmod(int(cells[v][p]), 7)
            y, x = 12 * y + 6, 12 * x + 6
            shine = np.clip(base + rng.normal(0, 0.12, 3), 0, 1) if p in shiny_points else None
            images[v][y - 3:y + 4, x - 3:x + 4] = base * [1.0, 1.1, 0.9][v % 3] if shine is None else shine
            track.append((v, x + 0.5, y + 0.5))
        tracks.append(np.array(track))
    return images, tracks


def _plan_on_patches(images, tracks, cams, prior=AUTO):
    size = images[0].shape[0]
    views = [View(camera=replace(c, width=size, height=size, cx=size / 2, cy=size / 2), image_path=None,
                  loader=lambda img=img: img) for c, img in zip(cams, images)]
    scene = Scene(views=views, splits={"train": list(range(len(views))), "test": []}, source="synthetic")
    tri = SimpleNamespace(points=np.zeros((len(tracks), 3)), colors=np.zeros((len(tracks), 3)),
                          errors=np.zeros(len(tracks)), tracks=tracks)
    return plan_effects(scene, TrainConfig(init="points"), prior, triangulation=tri, log=lambda m: None)


def test_view_dependence_from_tracks_in_images():
    n_views, n_pts = 16, 40
    flat, tracks = _patch_views(n_views, n_pts, shiny_points=())
    shiny, shiny_tracks = _patch_views(n_views, n_pts, shiny_points=range(n_pts))
    assert measure_view_dependence(flat, tracks)["spread_median"] < 0.02
    assert measure_view_dependence(shiny, shiny_tracks)["spread_median"] > 0.07
    # the plan reads the training images through the scene: shiny -> degree 3, flat -> 0 (16 views allow 3)
    for images, trk, expected in ((shiny, shiny_tracks, 3), (flat, tracks, 0)):
        p = _plan_on_patches(images, trk, ring(n_views))
        assert p["sh_degree"].value == expected and p["sh_degree"].source == "auto"
        assert p["sh_degree"].measured["points"] == n_pts


@pytest.mark.parametrize("n_views", [16, 8, 3])
def test_auto_on_an_orbit_gives_degree_2_when_a_tenth_of_the_points_shine(n_views):
    # 6 of 40 points shine: the median point is diffuse (degree 0), the p90 is not
    n_pts = 40
    images, tracks = _patch_views(n_views, n_pts, shiny_points=range(6))
    m = measure_view_dependence(images, tracks)
    assert m["spread_median"] < 0.02 <= m["spread_p90"]
    orbit = _plan_on_patches(images, tracks, ring(n_views))
    assert orbit["rig"].value == "object orbit"
    # 8 views identify degree 1 on their own: the orbit recipe goes past that cap, and says so; 3 views identify
    # degree 0 and stay there
    assert orbit["sh_degree"].value == (0 if n_views == 3 else 2) and "p90" in orbit["sh_degree"].reason
    assert orbit["sh_degree"].measured["identifiable_degree"] == {16: 3, 8: 1, 3: 0}[n_views]
    assert ("past the bare views' cap of 1" in orbit["sh_degree"].reason) == (n_views == 8)
    # plain 3DGS and other rigs keep the median's degree
    assert _plan_on_patches(images, tracks, ring(n_views), PriorConfig(prior="none"))["sh_degree"].value == 0
    forward = _plan_on_patches(images, tracks, row(n_views))
    assert forward["rig"].value == "forward-facing" and forward["sh_degree"].value == 0


def test_sh_degree_is_capped_by_the_number_of_views_and_unmeasurable_falls_back():
    p = plan_effects(make_scene(n_train=4), TrainConfig(init="points"), AUTO, triangulation=fake_triangulation(0),
                     log=lambda m: None)
    assert p["sh_degree"].value == 1 and "not measurable" in p["sh_degree"].reason


# -- a disabled effect costs nothing -------------------------------------------------------------------------
def _count(monkeypatch, module, name, calls, key):
    original = getattr(module, name)

    def wrapper(*a, **k):
        calls[key] = calls.get(key, 0) + 1
        return original(*a, **k)

    monkeypatch.setattr(module, name, wrapper)


def _train(scene, tmp_path, overrides, prior=AUTO, iters=4):
    from gsgs_engine.reconstruct import run_prior_training

    tc0 = TrainConfig(iters=iters, backend="reference", init="points", checkpoint_every=0, densify=False)
    p = plan(scene, prior, overrides, tri=fake_triangulation(len(scene.points)))
    tc, pc = apply_effect_plan(p, tc0, prior)
    with shared_triangulation(p, scene.train):
        return p, run_prior_training(scene, tc, pc, tmp_path / "out", None, plan={"effects": p.to_dict()})


def _install_counters(monkeypatch):
    import gsgs_engine.priors.poses as poses
    import gsgs_engine.priors.sparse_depth as sparse_depth
    import gsgs_engine.priors.warp_inpaint as warp_inpaint
    import gsgs_engine.render.project as project
    import gsgs_engine.sfm as sfm

    calls: dict = {}
    _count(monkeypatch, warp_inpaint, "warp_photos", calls, "generator")  # the generator, once a pseudo view
    _count(monkeypatch, poses, "interpolated_pseudo_views", calls, "pseudo_poses")
    _count(monkeypatch, sparse_depth.SparseDepthSource, "estimate", calls, "depth_source")
    monkeypatch.setattr(sfm, "triangulate_with_known_poses",
                        lambda *a, **k: calls.__setitem__("triangulate", calls.get("triangulate", 0) + 1))
    degrees: list[int] = []
    original = project.eval_sh
    monkeypatch.setattr(project, "eval_sh", lambda d, sh, dirs: (degrees.append(d), original(d, sh, dirs))[1])
    return calls, degrees


def test_disabled_effects_are_never_called(tmp_path, monkeypatch):
    calls, degrees = _install_counters(monkeypatch)
    scene = make_scene(n_train=24)  # dense: no pseudo views, no generator
    p, metrics = _train(scene, tmp_path, {"sh_degree": 0, "depth": "off"})
    assert not p["pseudo_views"].enabled and not p["depth"].enabled
    assert calls == {}  # no generator, no pseudo poses, no depth estimates, no triangulation
    assert degrees and set(degrees) == {0}  # SH of degree > 0 never evaluated ...
    from gsgs_engine.io.ply import read_gaussian_ply

    assert read_gaussian_ply(tmp_path / "out" / "point_cloud.ply").sh_rest.shape[1] == 0  # ... nor allocated
    saved = metrics["plan"]["effects"]
    assert saved["pseudo_views"]["enabled"] is False and saved["sh_degree"]["value"] == 0


def test_enabled_effects_are_called(tmp_path, monkeypatch):
    calls, degrees = _install_counters(monkeypatch)
    scene = make_scene(n_train=4, forward=True)  # sparse forward-facing: warp-inpaint pseudo views, sparse depth
    p, metrics = _train(scene, tmp_path, {"sh_degree": 1, "depth": "on"})
    assert p["generator"].value == "warp-inpaint" and p["depth"].value == "sparse"
    assert calls["generator"] == 2 and calls["pseudo_poses"] == 1 and calls["depth_source"] >= 4 + 2
    assert "triangulate" not in calls  # the plan's points are shared, not recomputed
    assert 1 in degrees
    assert metrics["plan"]["effects"]["generator"]["value"] == "warp-inpaint"
    assert metrics["prior_rounds"]


def test_overrides_from_a_command_line_typed_flags_win():
    import argparse

    from gsgs_engine.effect_plan import add_effects_argument, overrides_from_args

    parser = argparse.ArgumentParser()
    parser.add_argument("--sh-degree", type=int, default=None)
    add_effects_argument(parser)
    args = parser.parse_args(["--effects", "pseudo_views=4"])
    args.effects_overrides = {"sh_degree": 0, "pseudo_views": "off"}  # what a preset set
    assert overrides_from_args(args) == {"sh_degree": 0, "pseudo_views": 4}
    args = parser.parse_args(["--sh-degree", "2", "--effects", "depth=off"])
    assert overrides_from_args(args) == {"sh_degree": 2, "depth": "off"}
    with pytest.raises(GsgsError, match="unknown effect"):
        overrides_from_args(parser.parse_args(["--effects", "fog=on"]))


def test_position_learning_rate_of_the_recipe_and_as_asked():
    from gsgs_engine.effect_plan import POSITION_LR_SCALE

    orbit = plan(make_scene(n_train=4))  # a sparse object orbit under --prior auto: the recipe's multiple
    assert orbit["rig"].value == "object orbit"
    assert orbit["position_lr"].enabled and orbit["position_lr"].value == POSITION_LR_SCALE > 1
    assert "orbit" in orbit["position_lr"].reason and "position_lr" in orbit.format()
    assert apply_effect_plan(orbit, TrainConfig(), AUTO)[0].position_lr_scale == POSITION_LR_SCALE
    video = plan(make_scene(times=[0.0, 0.3, 0.6, 1.0]))
    assert video["position_lr"].value == POSITION_LR_SCALE and "4D" in video["position_lr"].reason
    front = plan(make_scene(n_train=4, forward=True))  # forward-facing: 3DGS's rate (measured lower there)
    assert front["position_lr"].enabled is False and front["position_lr"].value == 1.0
    assert apply_effect_plan(front, TrainConfig(), AUTO)[0].position_lr_scale == 1.0
    assert plan(make_scene(n_train=4), replace(AUTO, prior="none"))["position_lr"].value == 1.0  # the baseline
    assert plan(make_scene(n_train=24))["position_lr"].value == 1.0  # dense views: plain optimisation
    asked = plan(make_scene(n_train=4, forward=True), position_lr_scale=2.5)  # the user's multiple wins everywhere
    assert asked["position_lr"].value == 2.5 and asked["position_lr"].source == "user"
    assert apply_effect_plan(asked, TrainConfig(position_lr_scale=2.5), AUTO)[0].position_lr_scale == 2.5
    from gsgs_engine.effect_plan import AUTO_LONG_STEPS  # a long schedule moves the means far enough already

    for scene in (make_scene(n_train=4), make_scene(times=[0.0, 0.3, 0.6, 1.0])):
        long_run = plan(scene, iters=AUTO_LONG_STEPS)["position_lr"]
        assert long_run.value == 1.0 and long_run.enabled is False and str(AUTO_LONG_STEPS) in long_run.reason
        assert plan(scene, iters=AUTO_LONG_STEPS - 1)["position_lr"].value == POSITION_LR_SCALE
    assert plan(make_scene(n_train=4), iters=AUTO_LONG_STEPS, position_lr_scale=3.0)["position_lr"].value == 3.0
    kept = plan(make_scene(n_train=4), position_lr_scale=1.0)
    assert kept["position_lr"].value == 1.0 and kept["position_lr"].enabled is False and kept["position_lr"].source == "user"
    with pytest.raises(GsgsError, match="--position-lr-scale"):
        parse_overrides("position_lr=3")


def test_attribute_learning_rates_of_the_orbit_recipe_and_as_asked():
    from gsgs_engine.effect_plan import ATTRIBUTE_LR_SCALE, AUTO_LONG_STEPS

    orbit = plan(make_scene(n_train=4))  # a short sparse object orbit under --prior auto: the recipe's multiple
    assert orbit["attribute_lr"].enabled and orbit["attribute_lr"].value == ATTRIBUTE_LR_SCALE > 1
    assert "orbit" in orbit["attribute_lr"].reason and "attribute_lr" in orbit.format()
    assert apply_effect_plan(orbit, TrainConfig(), AUTO)[0].attribute_lr_scale == ATTRIBUTE_LR_SCALE
    front = plan(make_scene(n_train=4, forward=True))  # a forward-facing rig: measured too
    assert front["attribute_lr"].value == ATTRIBUTE_LR_SCALE and "forward-facing" in front["attribute_lr"].reason
    # measured on short orbits and forward rigs only: videos, long runs, plain 3DGS and dense views keep 3DGS's rates
    for other in (plan(make_scene(times=[0.0, 0.3, 0.6, 1.0])),
                  plan(make_scene(n_train=4), iters=AUTO_LONG_STEPS),
                  plan(make_scene(n_train=4), replace(AUTO, prior="none")), plan(make_scene(n_train=24))):
        assert other["attribute_lr"].enabled is False and other["attribute_lr"].value == 1.0
        assert apply_effect_plan(other, TrainConfig(), AUTO)[0].attribute_lr_scale == 1.0
    assert plan(make_scene(n_train=4), iters=AUTO_LONG_STEPS - 1)["attribute_lr"].value == ATTRIBUTE_LR_SCALE
    asked = plan(make_scene(n_train=4, forward=True), attribute_lr_scale=2.0)  # the user's multiple wins everywhere
    assert asked["attribute_lr"].value == 2.0 and asked["attribute_lr"].source == "user"
    kept = plan(make_scene(n_train=4), attribute_lr_scale=1.0)
    assert kept["attribute_lr"].value == 1.0 and kept["attribute_lr"].enabled is False
    with pytest.raises(GsgsError, match="--attribute-lr-scale"):
        parse_overrides("attribute_lr=3")
