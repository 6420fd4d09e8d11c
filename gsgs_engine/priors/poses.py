"""Pseudo poses (METHOD.md "Pseudo views"): where the prior hallucinates unseen views.

Interpolated between neighbouring training cameras (centres linearly, orientations by
slerp, optional jitter), for forward-facing rigs also on a ring around the cameras (views
past the rig's edges), plus any poses an artist authored in Blender. A pseudo pose keeps
the intrinsics of its nearest training camera and remembers that camera's index (the
geometry-aware loss warps into it).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from gsgs_engine.cameras import (Camera, interpolate_cameras, interpolate_cameras_around, quat_to_rotmat,
                                 rotmat_to_quat)
from gsgs_engine.priors.config import PriorConfig


@dataclass(frozen=True)
class PseudoView:
    camera: Camera
    nearest_train: int  # index into the training views
    source: str  # "interpolated" | "surrounding" | "authored"

    @property
    def name(self) -> str:
        return self.camera.name


def nearest_train_index(camera: Camera, train: list[Camera]) -> int:
    """The training camera closest in position, ties broken by viewing direction."""
    centres = np.stack([c.center for c in train])
    dist = np.linalg.norm(centres - camera.center, axis=1)
    forward = np.stack([c.R[2] for c in train])
    angle = 1.0 - forward @ camera.R[2]
    scale = max(float(dist.max()), 1e-9)
    return int(np.argmin(dist / scale + 0.1 * angle))


def neighbour_pairs(train: list[Camera], k: int = 2) -> list[tuple[int, int]]:
    """Undirected edges joining each training camera to its k nearest others, sorted."""
    centres = np.stack([c.center for c in train])
    d = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    edges = set()
    for i in range(len(train)):
        for j in np.argsort(d[i])[: min(k, len(train) - 1)]:
            edges.add((min(i, int(j)), max(i, int(j))))
    return sorted(edges)


def _with_intrinsics_of(camera: Camera, ref: Camera) -> Camera:
    return replace(camera, fx=ref.fx, fy=ref.fy, cx=ref.cx, cy=ref.cy, width=ref.width, height=ref.height,
                   near=ref.near, far=ref.far)


def _jitter(camera: Camera, rng: np.random.Generator, position_sigma: float, angle_sigma_deg: float) -> Camera:
    axis = rng.normal(size=3)
    axis /= max(np.linalg.norm(axis), 1e-12)
    half = np.deg2rad(rng.normal() * angle_sigma_deg) / 2
    dq = np.concatenate([[np.cos(half)], np.sin(half) * axis])
    c2w = quat_to_rotmat(dq) @ camera.R.T
    R = c2w.T
    centre = camera.center + rng.normal(size=3) * position_sigma
    return replace(camera, R=R, t=-R @ centre)


def interpolated_pseudo_views(train: list[Camera], count: int, jitter: float = 0.0, seed: int = 0,
                              neighbours: int = 2, time: float | None = None,
                              focus=None) -> list[PseudoView]:
    """`count` poses spread evenly over the edges between neighbouring training cameras.

    With a `focus` (the point the cameras look at), centres travel on arcs around it rather
    than on straight lines, so views between orbiting cameras stay at the cameras' distance.

    `jitter` is relative: positions move by jitter x the edge length (standard deviation) and
    orientations by jitter x 10 degrees.
    """
    if count <= 0 or len(train) < 2:
        return []
    edges = neighbour_pairs(train, neighbours)
    rng = np.random.default_rng(seed)
    per_edge = np.full(len(edges), count // len(edges))
    per_edge[: count % len(edges)] += 1
    views = []
    for (i, j), n in zip(edges, per_edge):
        for s in range(n):
            t = (s + 1) / (n + 1)
            name = f"pseudo_{len(views):03d}"
            cam = (interpolate_cameras(train[i], train[j], t, name=name) if focus is None
                   else interpolate_cameras_around(train[i], train[j], t, focus, name=name))
            if jitter > 0:
                length = float(np.linalg.norm(train[i].center - train[j].center))
                cam = _jitter(cam, rng, jitter * length, jitter * 10.0)
            near = nearest_train_index(cam, train)
            cam = _with_intrinsics_of(cam, train[near])
            if time is not None:
                cam = replace(cam, time=time)
            views.append(PseudoView(cam, near, "interpolated"))
    return views


def surrounding_pseudo_views(train: list[Camera], count: int, reach: float = PriorConfig.reach,
                             first_index: int = 0) -> list[PseudoView]:
    """`count` poses on a ring around a forward-facing rig, beyond the training cameras.

    The ring lies in the plane across the mean viewing direction, centred on the cameras'
    centroid, with radius `reach` x the rig's radius (the largest centre-to-centroid distance),
    its first pose along the cameras' mean right axis. Each pose looks the way its nearest
    training camera looks and takes its intrinsics. Interpolated poses stay inside the rig;
    these see past its edges, where novel views in any direction lose content (measured on
    llff_flower 3 views: test views beside the rig showed ~20% empty image).
    """
    if count <= 0 or len(train) < 2 or reach <= 0:
        return []
    centres = np.stack([c.center for c in train])
    centroid = centres.mean(axis=0)
    radius = float(np.linalg.norm(centres - centroid, axis=1).max())
    if radius < 1e-9:
        return []
    forward = np.mean([c.R[2] for c in train], axis=0)
    forward /= max(float(np.linalg.norm(forward)), 1e-12)
    right = np.mean([c.R[0] for c in train], axis=0)
    right -= forward * float(right @ forward)
    if float(np.linalg.norm(right)) < 1e-9:
        return []
    right /= float(np.linalg.norm(right))
    down = np.cross(forward, right)
    views = []
    for k in range(count):
        angle = 2.0 * np.pi * k / count
        centre = centroid + reach * radius * (np.cos(angle) * right + np.sin(angle) * down)
        near = int(np.argmin(np.linalg.norm(centres - centre, axis=1)))
        ref = train[near]
        cam = replace(ref, t=-ref.R @ centre, name=f"pseudo_{first_index + k:03d}")
        views.append(PseudoView(cam, near, "surrounding"))
    return views


def authored_pseudo_views(poses: list[dict], train: list[Camera]) -> list[PseudoView]:
    """Poses from job.json ("pseudo_poses": Camera.to_dict entries, e.g. sampled along a Blender path)."""
    views = []
    for k, d in enumerate(poses):
        cam = Camera.from_dict(d, source=f"job.json pseudo_poses[{k}]")
        near = nearest_train_index(cam, train)
        cam = _with_intrinsics_of(replace(cam, name=cam.name or f"authored_{k:03d}"), train[near])
        views.append(PseudoView(cam, near, "authored"))
    return views


def rotation_angle_deg(a: Camera, b: Camera) -> float:
    """Angle between two cameras' orientations (for tests and reports)."""
    q = rotmat_to_quat(a.R @ b.R.T)
    return float(np.rad2deg(2 * np.arccos(np.clip(abs(q[0]), 0.0, 1.0))))
