"""Optical-flow matches triangulated with known poses (gsgs_engine.init.flow_matches) on views of a known plane."""

from __future__ import annotations

import numpy as np
import pytest

from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera
from gsgs_engine.init.flow_matches import FlowConfig, combine_depths, flow_points, triangulate_midpoint
from gsgs_engine.init.mvs import MVSConfig, dense_points
from tests.test_mvs_init import PLANE_Z, plane_view, texture


def test_midpoint_triangulation_recovers_a_point_and_its_angle():
    a = Camera(R=np.eye(3), t=np.zeros(3), fx=100.0, fy=100.0, cx=50.0, cy=40.0, width=100, height=80)
    b = Camera(R=np.eye(3), t=-np.array([1.0, 0.0, 0.0]), fx=100.0, fy=100.0, cx=50.0, cy=40.0, width=100, height=80)
    world = np.array([[0.3, -0.2, 4.0], [0.5, 0.5, 8.0]])
    uv_a, _ = a.project(world)
    uv_b, _ = b.project(world)
    pts, angle = triangulate_midpoint(a, b, uv_a, uv_b)
    assert np.allclose(pts, world, atol=1e-9)
    expected = np.degrees(np.arccos(np.sum((world - a.center) * (world - b.center), 1)
                                    / np.linalg.norm(world - a.center, axis=1) / np.linalg.norm(world - b.center, axis=1)))
    assert np.allclose(angle, expected, atol=1e-6)
    # parallel rays (a point at infinity): NaN, never a point at a huge finite distance
    pts, angle = triangulate_midpoint(a, b, np.array([[50.0, 40.0]]), np.array([[50.0, 40.0]]))
    assert np.isnan(pts).all() and angle[0] == 0.0


def test_sources_must_agree_and_a_disagreement_drops_the_pixel():
    nan = np.nan
    d = np.array([[1.0, 1.0, nan, 2.0, nan],
                  [1.005, 1.2, 3.0, nan, nan]])
    two = combine_depths(d, 0.01, 2)
    assert np.allclose(two[0], 1.0025) and np.isnan(two[1:]).all()
    one = combine_depths(d, 0.01, 1)  # a lone match is kept; two that disagree still are not
    assert np.allclose(one[[0, 2, 3]], [1.0025, 3.0, 2.0]) and np.isnan(one[[1, 4]]).all()


@pytest.mark.parametrize("method", ["dis", "deepflow"])
def test_flow_points_lie_on_the_plane(method):
    tex = texture(seed=4)
    views = [plane_view(x, tex, w=160, h=120) for x in (-0.25, 0.0, 0.25)]  # 3.5 and 7 px of disparity
    logs: list[str] = []
    fp = flow_points(views, FlowConfig(method=method, stride=1, min_angle_deg=0.5), log=logs.append)
    assert len(fp.points) > 0.3 * 3 * 160 * 120 and np.isfinite(fp.points).all()
    z = fp.points[:, 2]
    # flow is sub-pixel but smoothed: at 3.5-7 px of disparity DIS measures ~1 % short (0.05 px), hence 2 %
    assert np.median(np.abs(z - PLANE_Z) / PLANE_Z) < 0.02 and np.percentile(np.abs(z - PLANE_Z), 95) < 0.25
    assert (fp.colors >= 0).all() and (fp.colors <= 1).all() and fp.stats["points"] == len(fp.points)
    assert any(method in m for m in logs)


def test_rays_too_parallel_or_one_view_give_no_points():
    tex = texture(seed=5)
    close = [plane_view(x, tex) for x in (0.0, 0.01)]  # a 0.1 degree baseline: depth undetermined
    assert len(flow_points(close, FlowConfig(min_sources=1), log=lambda m: None).points) == 0
    assert len(flow_points(close[:1], log=lambda m: None).points) == 0


def test_flat_and_non_finite_images_give_finite_output():
    views = [plane_view(x, texture(), flat=True) for x in (-0.4, 0.0, 0.4)]
    fp = flow_points(views, FlowConfig(min_sources=1), log=lambda m: None)
    assert np.isfinite(fp.points).all()  # a flat image matches everywhere and nowhere: whatever survives is finite
    tex = texture(seed=6)
    tex[10:40, 10:40] = np.nan
    bad = [plane_view(x, tex) for x in (-0.4, 0.0, 0.4)]
    assert np.isfinite(flow_points(bad, log=lambda m: None).points).all()


def test_fused_into_the_stereo_points_and_recorded():
    tex = texture(seed=7)
    views = [plane_view(x, tex) for x in (-0.4, 0.0, 0.4)]
    plain = dense_points(views, config=MVSConfig(num_depths=48), log=lambda m: None)
    fused = dense_points(views, config=MVSConfig(num_depths=48, flow="dis"), log=lambda m: None)
    assert fused.stats["flow_points"] > 0 and fused.stats["mvs_points"] == plain.stats["mvs_points"]
    assert len(fused.points) == len(plain.points) + fused.stats["flow_points"]
    assert "optical-flow matches (dis)" in fused.reason
    with pytest.raises(GsgsError, match="flow"):
        MVSConfig(flow="raft").validate()
    with pytest.raises(GsgsError, match="method"):
        FlowConfig(method="raft").validate()
    with pytest.raises(GsgsError, match="min_sources"):
        FlowConfig(min_sources=3).validate()
