"""The dynamic-region score of `gsgs bench dynamic`: masked PSNR, changing pixels, foreground masks, and
the bench on a tiny Panoptic capture with several camera counts."""

from __future__ import annotations

import json
import math
from pathlib import Path
from argparse import Namespace

import cv2
import numpy as np
import pytest
import torch

from gsgs_engine import GsgsError
from gsgs_engine.bench.dynamic import parse_camera_counts
from gsgs_engine.bench.dynamic_region import CHANGE_THRESHOLD, changing_pixels, region_masks
from gsgs_engine.metrics import masked_psnr, psnr
from gsgs_engine.render.project import DEFAULT_NEAR
from tests.test_io_panoptic import TEST_IDS, write_capture


def test_masked_psnr_scores_only_the_region():
    rng = np.random.default_rng(0)
    gt = torch.from_numpy(rng.random((12, 16, 3), dtype=np.float32))
    img = gt.clone()
    img[2:6, 3:9] += 0.1  # an error inside the region only
    region = np.zeros((12, 16), bool)
    region[2:6, 3:9] = True
    assert masked_psnr(img, gt, region) == pytest.approx(20.0, abs=1e-3)  # mse 0.01 over the region
    assert masked_psnr(img, gt, np.ones((12, 16), bool)) == pytest.approx(float(psnr(img, gt)), abs=1e-4)
    assert masked_psnr(img, gt, ~region) == math.inf  # no error outside the region
    assert masked_psnr(img, gt, np.zeros((12, 16), bool)) is None
    with pytest.raises(ValueError, match="mask is"):
        masked_psnr(img, gt, np.ones((6, 8), bool))


def test_evaluation_scores_the_region_and_the_rest_apart():
    from types import SimpleNamespace

    from gsgs_engine.train.evaluate import evaluate_views

    rng = np.random.default_rng(1)
    gt = rng.random((12, 16, 3), dtype=np.float32) * 0.5
    region = np.zeros((12, 16), bool)
    region[2:6, 3:9] = True
    render = gt.copy()
    render[region] += 0.1  # mse 0.01 inside the region
    render[~region] += 0.01  # mse 1e-4 outside it
    view = SimpleNamespace(name="cam/0", camera=SimpleNamespace(name="cam"), image=lambda: gt)
    ev = evaluate_views(lambda cam: SimpleNamespace(color=torch.from_numpy(render)), [view],
                        region_fn=lambda v: region, lpips=False)
    assert ev["psnr_region"] == pytest.approx(20.0, abs=1e-3)
    assert ev["psnr_outside"] == pytest.approx(40.0, abs=1e-3)
    assert ev["per_view"][0]["psnr_outside"] == ev["psnr_outside"]
    share = region.mean()  # the whole view's mse mixes the two by their pixel shares
    assert ev["psnr"] == pytest.approx(-10 * math.log10(share * 0.01 + (1 - share) * 1e-4), abs=1e-3)


def test_changing_pixels_find_what_moves():
    frames = []
    for f in range(5):
        im = np.full((10, 20, 3), 0.4, np.float32)
        im[4:6, 2 + 3 * f:4 + 3 * f] = 0.9  # a bright block moving right
        im += np.float32(0.3 * CHANGE_THRESHOLD) * (f % 2)  # flicker below the threshold: not motion
        frames.append(im)
    masks = changing_pixels(frames)
    for f, m in enumerate(masks):
        expected = np.zeros((10, 20), bool)
        expected[4:6, 2 + 3 * f:4 + 3 * f] = True
        assert np.array_equal(m, expected), f
    with pytest.raises(ValueError, match="at least 3 frames"):
        changing_pixels(frames[:2])


@pytest.fixture
def pano(tmp_path):
    return write_capture(tmp_path / "pano", frames=3)


def test_region_masks_prefer_the_capture_masks(pano):
    from gsgs_engine.io import load_scene

    scene = load_scene(pano, train_views=3)
    fn, what = region_masks(scene.train)  # training cameras have seg/ masks
    assert "foreground masks" in what
    m = fn(scene.train[0])
    assert m.dtype == bool and m[3, 5] and not m[0, 0]
    fn, what = region_masks(scene.test)  # test cameras have none: the pixels that change over time
    assert "change over time" in what
    masks = [fn(v) for v in scene.test]
    assert all(m is not None and m.shape == (12, 16) for m in masks)
    assert masks[0].any()  # the tiny capture's colour moves 40/255 a frame
    fn, _ = region_masks([v for v in scene.test if v.camera.extra["frame"] < 2])
    assert fn(scene.test[0]) is None  # two frames of a camera: no median, no region


def test_camera_counts_are_parsed():
    assert parse_camera_counts("3,6,9") == [3, 6, 9] and parse_camera_counts(3) == [3]
    for bad in ("", "0", "3,x", "-1"):
        with pytest.raises(GsgsError, match="--cameras"):
            parse_camera_counts(bad)


def test_bench_on_a_panoptic_capture_with_two_camera_counts(pano, tmp_path):
    from gsgs_engine.bench.dynamic import run

    out = tmp_path / "bench"
    args = Namespace(cameras="2,3", out=str(out), data=str(pano), ring=10, frames=3, size=64, samples=4, iters=6,
                     per_frame_iters=3, init="mvs", init_points=60, sh_degree=0, backend="auto", seed=0,
                     threads=0, resolution_scale=1.0, no_lpips=True, rig="auto",
                     techniques="exposure", models="4d,static_all,static_per_frame", background="mean",
                     position_lr_scale=3.0)
    assert run(args) == 0
    every = json.loads((out / "results.json").read_text())["cameras"]
    assert sorted(every) == ["2", "3"]
    for n, results in every.items():
        setup = results["setup"]
        assert setup["format"] == "panoptic" and len(setup["train_cameras"]) == int(n)
        assert setup["test_cameras"] == TEST_IDS and setup["frames"] == 3 and setup["lpips"] == "none"
        assert setup["machine"]["cpu"] and setup["machine"]["threads"] >= 1  # which machine (gsgs_engine.machine)
        assert "change over time" in results["region"]
        assert results["4d"]["init"]["method"] == "mvs" and results["static_all"]["init"]["method"] != "random"
        assert results["rig"]["rig"] in ("object orbit", "forward-facing", "inward shell")
        assert results["novel_view_near"] == (results["rig"]["near"] or DEFAULT_NEAR)
        # --background mean: the training photos' mean colour, not the loader's white
        assert results["background"] == "mean" and not np.allclose(results["background_colour"], 1.0)
        assert results["position_lr_scale"] == 3.0  # every model's, recorded
        for name in ("4d", "static_all", "static_per_frame"):
            r = results[name]
            assert len(r["per_view"]) == 6  # two test cameras x three frames
            assert np.isfinite(r["psnr"]) and np.isfinite(r["psnr_region"]) and r["lpips"] is None
            # the rest of each view (a video's still room) scored apart from the region, per view
            assert np.isfinite(r["psnr_outside"])
            assert all(v["psnr_outside"] is None or np.isfinite(v["psnr_outside"]) for v in r["per_view"])
            if name != "static_per_frame":  # one model: its techniques' reports (per-camera exposure)
                assert r["techniques"]["exposure"]["cameras"] == int(n)
        assert (out / f"cameras_{n}" / "results.json").is_file()
        assert (out / f"cameras_{n}" / "4d" / "point_cloud.ply").is_file()
        picture = cv2.imread(str(out / f"cameras_{n}" / "comparison.png"))  # ground truth | 4D | best static
        view = results["4d"]["per_view"][0]
        assert picture is not None and picture.shape[:2] == (3 * 12, 3 * 16), view  # three frames of 16x12 views
    table = (out / "results.md").read_text()
    assert table.count("| 2 | ") == 3 and table.count("| 3 | ") == 3 and "dynamic region PSNR" in table
    assert "PSNR outside it" in table


PANOPTIC = Path(__file__).resolve().parents[2] / "shared" / "data" / "panoptic_basketball"


@pytest.mark.slow
@pytest.mark.skipif(not PANOPTIC.is_dir(), reason=f"{PANOPTIC} absent (../shared/data)")
def test_the_bench_reads_the_panoptic_dome_as_a_shell_and_draws_test_views_with_its_near_plane():
    """As gsgs train does (tests/test_rig.py): 9 cameras of the dome are an inward shell, whose test cameras sit in
    the wall the training cameras see; the bench records the rig and the near plane its test views are drawn with."""
    from gsgs_engine.bench.dynamic import bench_rig, load_bench_scene

    scene = load_bench_scene(PANOPTIC, 9, 1, 0.5)
    layout = bench_rig(scene, log=lambda m: None)
    assert layout["rig"] == "inward shell" and layout["points_at_shell"] >= 0.2
    assert 0.1 < layout["near"] < 1.0  # 0.1 x the dome's radius (about 2.7 units)
    three = load_bench_scene(PANOPTIC, 3, 1, 0.5)  # too far apart to triangulate: RGB photos read as a shell ...
    guessed = bench_rig(three, log=lambda m: None)
    assert guessed["rig"] == "inward shell" and guessed["unmeasured"] and 0.1 < guessed["near"] < 1.0
    told = bench_rig(three, "orbit", log=lambda m: None)  # ... unless the user says otherwise
    assert told["near"] is None
    # another time window of the same capture (--first-frame): frames 10-11, times normalised over them
    later = load_bench_scene(PANOPTIC, 3, 2, 0.5, first_frame=10)
    assert sorted({v.name.split("/")[1] for v in later.train}) == ["000010", "000011"]
    assert sorted({v.camera.time for v in later.train}) == [0.0, 1.0]


def test_the_bench_can_screen_one_model_and_refuses_unknown_ones(pano, tmp_path):
    from gsgs_engine.bench.dynamic import run

    args = Namespace(cameras="2", out=str(tmp_path / "one"), data=str(pano), ring=10, frames=3, size=64, samples=4,
                     iters=4, per_frame_iters=2, init="random", init_points=60, sh_degree=0, backend="auto", seed=0,
                     threads=0, resolution_scale=1.0, no_lpips=True, rig="orbit", techniques=None, models="4d",
                     background="opaque", position_lr_scale=1.0)
    assert run(args) == 0
    results = json.loads((tmp_path / "one" / "results.json").read_text())
    assert "4d" in results and "static_all" not in results and "static_per_frame" not in results
    assert results["rig"]["near"] is None and results["novel_view_near"] == DEFAULT_NEAR  # --rig orbit
    assert results["background"] == results["setup"]["background"] == "opaque"
    with pytest.raises(GsgsError, match="--models"):
        run(Namespace(**{**vars(args), "models": "4d,nope"}))
    with pytest.raises(GsgsError, match="frame 3 does not exist"):  # a window past the capture's 3 frames
        run(Namespace(**{**vars(args), "first_frame": 3}))
    with pytest.raises(GsgsError, match="--first-frame"):
        run(Namespace(**{**vars(args), "first_frame": -1}))
    for bad in (0.0, float("nan"), 1000.0):
        with pytest.raises(GsgsError, match="--position-lr-scale"):
            run(Namespace(**{**vars(args), "position_lr_scale": bad}))
