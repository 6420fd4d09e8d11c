"""Pseudo poses: interpolation between neighbouring cameras, nearest-view bookkeeping, authored poses."""

import numpy as np
import pytest

from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera, look_at
from gsgs_engine.priors.poses import (authored_pseudo_views, interpolated_pseudo_views, nearest_train_index,
                                      neighbour_pairs, rotation_angle_deg, surrounding_pseudo_views)


def _ring(n=6, radius=4.0, w=40, h=30):
    cams = []
    for k in range(n):
        a = 2 * np.pi * k / n
        eye = np.array([radius * np.cos(a), radius * np.sin(a), 1.0])
        R, t = look_at(eye, np.zeros(3))
        cams.append(Camera(R=R, t=t, fx=30 + k, fy=30 + k, cx=w / 2, cy=h / 2, width=w, height=h, name=f"c{k}"))
    return cams


def test_count_nearest_and_intrinsics():
    train = _ring()
    views = interpolated_pseudo_views(train, 10)
    assert len(views) == 10 and len({v.name for v in views}) == 10
    for v in views:
        assert v.nearest_train == nearest_train_index(v.camera, train)
        ref = train[v.nearest_train]
        assert (v.camera.fx, v.camera.width, v.camera.height) == (ref.fx, ref.width, ref.height)
        v.camera.validate()


def test_interpolated_poses_lie_between_their_neighbours_and_look_at_the_scene():
    train = _ring(n=4)
    for v in interpolated_pseudo_views(train, 8):
        # Orientation between two ring cameras 90 degrees apart: at most 90 degrees from the nearest.
        assert rotation_angle_deg(v.camera, train[v.nearest_train]) <= 45.0 + 1e-6
        uv, z = v.camera.project(np.zeros((1, 3)))
        assert z[0] > 0 and 0 < uv[0, 0] < v.camera.width and 0 < uv[0, 1] < v.camera.height


def test_jitter_is_seeded_and_moves_poses():
    train = _ring()
    a = interpolated_pseudo_views(train, 5, jitter=0.1, seed=1)
    b = interpolated_pseudo_views(train, 5, jitter=0.1, seed=1)
    c = interpolated_pseudo_views(train, 5, jitter=0.0)
    assert all(np.allclose(x.camera.t, y.camera.t) for x, y in zip(a, b))
    assert any(not np.allclose(x.camera.t, y.camera.t) for x, y in zip(a, c))


def test_edges_and_degenerate_inputs():
    train = _ring(n=5)
    edges = neighbour_pairs(train)
    assert (0, 1) in edges and (0, 4) in edges and all(i < j for i, j in edges)
    assert interpolated_pseudo_views(train[:1], 4) == []
    assert interpolated_pseudo_views(train, 0) == []
    two = interpolated_pseudo_views(train[:2], 3)
    assert len(two) == 3


def test_authored_poses_keep_nearest_intrinsics_and_reject_bad_entries():
    train = _ring()
    R, t = look_at(np.array([4.0, 0.3, 1.2]), np.zeros(3))
    d = Camera(R=R, t=t, fx=99, fy=99, cx=5, cy=5, width=10, height=10).to_dict()
    (v,) = authored_pseudo_views([d], train)
    assert v.source == "authored" and v.nearest_train == 0 and v.camera.width == train[0].width
    bad = dict(d, t=[float("nan"), 0, 0])
    with pytest.raises(GsgsError, match="pseudo_poses\\[0\\]"):
        authored_pseudo_views([bad], train)


def test_orbit_interpolation_keeps_pseudo_views_at_the_cameras_distance():
    """Cameras on a circle around the origin, 90 degrees apart: the arc midpoint stays at radius 4
    (a straight line would pass at 4 cos 45 = 2.83) and still looks at the focus."""
    from gsgs_engine.cameras import Camera, look_at
    from gsgs_engine.train.techniques.prior_loop import orbit_focus
    from gsgs_engine.priors.poses import interpolated_pseudo_views

    cams = []
    for k in range(4):
        eye = 4.0 * np.array([np.cos(k * np.pi / 2), np.sin(k * np.pi / 2), 0.3])
        R, t = look_at(eye, np.zeros(3))
        cams.append(Camera(R=R, t=t, fx=50, fy=50, cx=32, cy=32, width=64, height=64, name=f"c{k}"))
    focus = orbit_focus(cams)
    assert focus is not None and np.allclose(focus, 0.0, atol=1e-6)
    radius = np.linalg.norm(cams[0].center)
    arc = interpolated_pseudo_views(cams, 4, focus=focus, neighbours=1)
    line = interpolated_pseudo_views(cams, 4, neighbours=1)
    for p in arc:
        assert np.isclose(np.linalg.norm(p.camera.center), radius, rtol=1e-9)
        assert np.degrees(np.arccos(np.clip(p.camera.R[2] @ (-p.camera.center / radius), -1, 1))) < 1e-3
    assert all(np.linalg.norm(p.camera.center) < 0.8 * radius for p in line)
    # forward-facing rigs have no crossing point: straight lines, as before
    fwd = [Camera(R=np.eye(3), t=np.array([-x, 0.0, 0.0]), fx=50, fy=50, cx=32, cy=32, width=64, height=64)
           for x in (0.0, 0.5, 1.0)]
    assert orbit_focus(fwd) is None


def _forward_rig(w=40, h=30):
    """Three cameras in a vertical line, all looking down +z (a handheld LLFF-style capture)."""
    cams = []
    for k, y in enumerate((-1.0, 0.2, 1.3)):
        eye = np.array([0.1 * k, y, -5.0])
        R, t = look_at(eye, eye + np.array([0.0, 0.0, 10.0]), up=(0.0, -1.0, 0.0))
        cams.append(Camera(R=R, t=t, fx=40 + k, fy=40 + k, cx=w / 2, cy=h / 2, width=w, height=h, name=f"f{k}"))
    return cams


def test_surrounding_poses_ring_the_rig_at_the_requested_reach():
    train = _forward_rig()
    centres = np.stack([c.center for c in train])
    centroid = centres.mean(0)
    radius = np.linalg.norm(centres - centroid, axis=1).max()
    views = surrounding_pseudo_views(train, 4, reach=2.0, first_index=7)
    assert [v.name for v in views] == ["pseudo_007", "pseudo_008", "pseudo_009", "pseudo_010"]
    for v in views:
        offset = v.camera.center - centroid
        assert np.isclose(np.linalg.norm(offset), 2.0 * radius)
        assert abs(offset @ np.array([0.0, 0.0, 1.0])) < 1e-9  # in the plane across the viewing direction
        ref = train[v.nearest_train]
        assert v.nearest_train == int(np.argmin(np.linalg.norm(centres - v.camera.center, axis=1)))
        assert np.allclose(v.camera.R, ref.R) and v.camera.fx == ref.fx and v.source == "surrounding"
        v.camera.validate()
    # the first pose lies along the rig's right axis: beyond the rig sideways, where no camera went
    assert views[0].camera.center[0] - centroid[0] > 1.9 * radius
    assert surrounding_pseudo_views(train, 0) == [] and surrounding_pseudo_views(train, 4, reach=0.0) == []
    assert surrounding_pseudo_views(train[:1], 4) == []
