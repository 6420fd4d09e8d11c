"""Which views of a scene train: the split, explicit ids or N evenly spaced views; and the background check."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gsgs_engine import GsgsError
from gsgs_engine.io.scene import Scene


def check_background(background) -> np.ndarray:
    bg = np.asarray(background, dtype=np.float32).reshape(-1)
    if bg.shape != (3,) or not np.all(np.isfinite(bg)) or bg.min() < 0 or bg.max() > 1:
        raise GsgsError(f"background must be three numbers in [0, 1] (RGB), got {background!r}")
    return bg


def select_train(scene: Scene, train_split: str | None = None, train_ids: list | None = None,
                 train_views: int | None = None) -> Scene:
    """Set scene.splits["train"] from the pool (split `train_split`, else "all_train", else "train")."""
    if train_ids is not None and train_views is not None:
        raise GsgsError("pass either train_ids or train_views, not both")
    if train_split is not None:
        if train_split not in scene.splits:
            raise GsgsError(f"{scene.source}: no split {train_split!r} to train on; available: "
                            f"{', '.join(scene.splits)}")
        pool = list(scene.splits[train_split])
    else:
        pool = list(scene.splits.get("all_train", scene.splits["train"]))
    scene.splits["all_train"] = pool
    if train_ids is not None:
        scene.splits["train"] = [pool[i] for i in _resolve_ids(scene, pool, train_ids)]
    elif train_views is not None:
        scene.splits["train"] = [pool[i] for i in evenly_spaced(len(pool), train_views, scene.source)]
    else:
        scene.splits["train"] = list(pool)
    return scene


def evenly_spaced(count: int, n: int, source: str = "scene") -> list[int]:
    """n indices spread over range(count), ends included: round(linspace(0, count - 1, n))."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise GsgsError(f"train_views must be a positive whole number, got {n!r}")
    if n > count:
        raise GsgsError(f"{source}: train_views={n} but only {count} candidate training views; ask for at most {count}")
    return [int(i) for i in np.round(np.linspace(0, count - 1, n))]


def _resolve_ids(scene: Scene, pool: list[int], train_ids) -> list[int]:
    """Positions in `pool` of train_ids given as positions (ints) or view names / file stems (strings)."""
    by_name: dict[str, int] = {}
    for pos, idx in enumerate(pool):
        view = scene.views[idx]
        by_name.setdefault(view.name, pos)
        by_name.setdefault(Path(view.name).name, pos)
        if view.image_path is not None:
            by_name.setdefault(Path(view.image_path).name, pos)
            by_name.setdefault(Path(view.image_path).stem, pos)
    out = []
    for item in train_ids:
        if isinstance(item, (int, np.integer)) and not isinstance(item, bool):
            if not 0 <= item < len(pool):
                raise GsgsError(f"{scene.source}: train id {item} is out of range; the pool has {len(pool)} views "
                                f"(ids 0..{len(pool) - 1})")
            pos = int(item)
        elif isinstance(item, str) and item in by_name:
            pos = by_name[item]
        elif isinstance(item, str) and item.strip().isdigit() and int(item) < len(pool):
            pos = int(item)  # "5" from a command line: a position, unless a view is named "5"
        else:
            raise GsgsError(f"{scene.source}: train id {item!r} names no candidate training view; use positions "
                            f"0..{len(pool) - 1} or view names such as {scene.views[pool[0]].name!r}")
        if pos in out:
            raise GsgsError(f"{scene.source}: train id {item!r} is listed twice")
        out.append(pos)
    if not out:
        raise GsgsError(f"{scene.source}: train_ids is empty; list at least one training view")
    return out
