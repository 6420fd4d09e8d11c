"""The initialisation's cache across jobs (gsgs_engine.init.cache): a repeat of the same views and settings is
served from it with the same result, any change misses, a damaged entry is computed again, "off" writes nothing."""

from __future__ import annotations

import os

import numpy as np
import pytest

from gsgs_engine import sfm
from gsgs_engine.init import cache as init_cache
from gsgs_engine.init.mvs import MVSConfig, dense_points
from gsgs_engine.io.scene import View

from test_mvs_init import plane_view, texture


@pytest.fixture
def cache_dir(tmp_path, monkeypatch):
    folder = tmp_path / "init_cache"
    monkeypatch.setenv("GSGS_INIT_CACHE", str(folder))
    return folder


def _sweep(views, logs=None, **cfg):
    return dense_points(views, config=MVSConfig(num_depths=32, **cfg), log=(logs.append if logs is not None
                                                                           else (lambda _m: None)))


def test_dense_init_is_reused_for_the_same_views_and_settings(cache_dir):
    views = [plane_view(x, texture(seed=4)) for x in (-0.4, 0.0, 0.4)]
    logs: list[str] = []
    first = _sweep(views, logs)
    assert any(m.startswith("mvs: view 1/3") for m in logs) and "cached" not in first.stats
    assert len(list((cache_dir / "mvs").glob("*.npz"))) == 1
    logs.clear()
    again = _sweep(views, logs)
    assert not any(m.startswith("mvs: view") for m in logs) and any("init cache" in m for m in logs)
    assert np.array_equal(again.points, first.points) and np.array_equal(again.colors, first.colors)
    assert again.points.dtype == np.float32 and again.method == first.method
    assert again.reason.startswith(first.reason + "; reused from the init cache")  # metrics.json's init.reason says so
    assert again.stats["cached"] is True and again.stats["views"] == first.stats["views"]
    assert again.stats["computed_seconds"] == first.stats["seconds"]


def test_a_changed_pixel_or_setting_misses(cache_dir):
    tex = texture(seed=5)
    views = [plane_view(x, tex) for x in (-0.4, 0.0, 0.4)]
    _sweep(views)
    changed = views[0].image().copy()
    changed[10, 10, 0] = 1.0 - changed[10, 10, 0]
    edited = [View(camera=views[0].camera, image_path=None, loader=lambda img=changed: img)] + views[1:]
    logs: list[str] = []
    _sweep(edited, logs)
    assert any(m.startswith("mvs: view 1/3") for m in logs)  # computed, not reused
    logs.clear()
    _sweep(views, logs, min_ncc=0.6)
    assert any(m.startswith("mvs: view 1/3") for m in logs)
    assert len(list((cache_dir / "mvs").glob("*.npz"))) == 3


def test_a_damaged_entry_is_computed_again_and_replaced(cache_dir, caplog):
    views = [plane_view(x, texture(seed=6)) for x in (-0.4, 0.0, 0.4)]
    first = _sweep(views)
    (entry,) = (cache_dir / "mvs").glob("*.npz")
    entry.write_bytes(b"not a zip file")
    logs: list[str] = []
    with caplog.at_level("WARNING", logger="gsgs.init.cache"):
        again = _sweep(views, logs)
    assert "damaged" in caplog.text and any(m.startswith("mvs: view 1/3") for m in logs)
    assert np.array_equal(again.points, first.points)
    assert init_cache.load_arrays("mvs", entry.stem) is not None  # the store replaced it


def test_off_writes_nothing(tmp_path, monkeypatch):
    monkeypatch.setenv("GSGS_INIT_CACHE", "off")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert init_cache.cache_root() is None
    views = [plane_view(x, texture(seed=7)) for x in (-0.4, 0.0, 0.4)]
    _sweep(views)
    _sweep(views)
    assert not any(tmp_path.rglob("*.npz"))
    monkeypatch.delenv("GSGS_INIT_CACHE")
    assert init_cache.cache_root() == tmp_path / "gsgs" / "init"


def test_only_the_newest_entries_are_kept(cache_dir, monkeypatch):
    monkeypatch.setattr(init_cache, "MAX_ENTRIES", 2)
    for i in range(3):
        init_cache.store_json("triangulation", f"k{i}", {"i": i})
        path = cache_dir / "triangulation" / f"k{i}.json"
        os.utime(path, (1000.0 + i, 1000.0 + i))  # distinct ages whatever the file system's clock resolution
    assert sorted(p.stem for p in (cache_dir / "triangulation").glob("*.json")) == ["k1", "k2"]
    assert init_cache.load_json("triangulation", "k0") is None and init_cache.load_json("triangulation", "k2") == {"i": 2}


def test_the_key_sees_array_dtype_shape_and_bytes():
    a = np.zeros((2, 3), np.float32)
    assert init_cache.key(a) == init_cache.key(a.copy())
    assert len({init_cache.key(a), init_cache.key(a.reshape(3, 2)), init_cache.key(a.astype(np.float64)),
                init_cache.key(a.tobytes()), init_cache.key(np.ones((2, 3), np.float32))}) == 5


def test_triangulation_is_reused_without_running_pycolmap_again(cache_dir, monkeypatch):
    """Real pycolmap once (SIFT on a textured plane seen from three known poses), then the cache."""
    tex = texture(size=512, seed=8)
    views = [plane_view(x, tex, w=320, h=240) for x in (-0.5, 0.0, 0.5)]
    runs = []
    real = sfm._run_in_child

    def counted(*args, **kwargs):
        runs.append(args[0])
        return real(*args, **kwargs)

    monkeypatch.setattr(sfm, "_run_in_child", counted)
    first = sfm.triangulate_with_known_poses(views)
    assert runs == ["triangulate"] and first.reason == "" and len(first.points) > 0
    messages = []
    again = sfm.triangulate_with_known_poses(views, progress=lambda *a: messages.append(a[-1]))
    assert runs == ["triangulate"] and any("init cache" in m for m in messages)
    assert np.array_equal(again.points, first.points) and np.array_equal(again.errors, first.errors)
    assert [t.tolist() for t in again.tracks] == [t.tolist() for t in first.tracks]
    assert again.num_features == first.num_features
    # a folder for the COLMAP files asks for them: computed
    sfm.triangulate_with_known_poses(views, out_dir=cache_dir.parent / "tri")
    assert runs == ["triangulate", "triangulate"] and (cache_dir.parent / "tri" / "database.db").is_file()


def test_a_value_that_cannot_be_stored_is_skipped_not_raised(cache_dir, caplog):
    with caplog.at_level("WARNING", logger="gsgs.init.cache"):
        init_cache.store_json("triangulation", "odd", {"points": np.zeros((2, 3), np.float32), "x": object()})
    assert "not stored" in caplog.text and not (cache_dir / "triangulation" / "odd.json").exists()
    init_cache.store_json("triangulation", "arrays", {"points": np.arange(6, dtype=np.float32).reshape(2, 3) / 3,
                                                      "n": np.int64(2)})
    back = init_cache.load_json("triangulation", "arrays")
    assert np.array_equal(np.asarray(back["points"], np.float32), np.arange(6, dtype=np.float32).reshape(2, 3) / 3)
    assert back["n"] == 2
