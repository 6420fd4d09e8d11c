"""Presets fast / balanced / best in the add-on (real bpy) and in the engine's job path.

Preset values are read from gsgs_engine.presets.PRESETS, never written here: the table may change.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

bpy = pytest.importorskip("bpy")
from gsgs_blender import job_runner, preferences  # noqa: E402
from gsgs_blender.preferences import preset_matches  # noqa: E402
from test_blender_addon import addon  # noqa: E402,F401  (the registered add-on, jobs under tmp_path)
from gsgs_engine.job import Job, settings_with_preset  # noqa: E402
from gsgs_engine.presets import PRESET_NAMES, PRESETS, apply_preset  # noqa: E402

pytestmark = pytest.mark.blender

FIELDS = preferences.PRESET_FIELDS  # panel field -> preset key

# Finishes at once and leaves the job.json it was given; the operators' job folder is all that matters here.
FAKE_ENGINE = r'''
import sys
from gsgs_engine.job import Job
job = Job.open(sys.argv[1])
job.set_status("ok", "fake finished")
'''


@pytest.fixture(autouse=True)
def fake_engine(tmp_path, monkeypatch):
    script = tmp_path / "fake_engine.py"
    script.write_text(FAKE_ENGINE)
    monkeypatch.setattr(job_runner, "engine_command", lambda python, job_dir: [sys.executable, str(script), str(job_dir)])


def _field_values(s) -> dict:
    return {f: getattr(s, f) for f in FIELDS}


def _preset_values(name: str) -> dict:
    return {f: PRESETS[name][k] for f, k in FIELDS.items()}


def _off_preset(s, name: str) -> None:
    """Set every panel field to a value the preset does not have."""
    p = PRESETS[name]
    s.preset = "custom"
    s.iterations = p["iters"] + 7
    s.rounds = (p["rounds"] + 1) % 20
    s.resolution_scale = 0.5 if p["resolution_scale"] != 0.5 else 0.25
    s.max_side = p["max_side"] + 16
    s.generator = "warp" if p["prior"] != "warp" else "depth"


def test_enum_offers_custom_and_each_preset_with_its_settings_in_the_tooltip(addon):
    items = addon.gsgs.bl_rna.properties["preset"].enum_items
    assert [i.identifier for i in items] == ["custom", *PRESET_NAMES]
    # A new scene starts from the balanced preset (the engine's default schedule), its fields matching it.
    assert addon.gsgs.preset == "balanced" and preset_matches(addon.gsgs, "balanced")
    for name in PRESET_NAMES:
        p, tip = PRESETS[name], items[name].description
        for text in (f"{p['iters']} iterations", f"prior {p['prior']}", f"{p['pseudo_views']} pseudo views",
                     f"{p['rounds']} rounds", f"SH {p['sh_degree']}", f"backend {p['backend']}", "Measured: "):
            assert text in tip, (name, text, tip)


@pytest.mark.parametrize("name", PRESET_NAMES)
def test_choosing_a_preset_sets_the_training_fields(addon, name):
    s = addon.gsgs
    _off_preset(s, name)
    s.preset = name
    values = _field_values(s)
    assert values.pop("resolution_scale") == pytest.approx(PRESETS[name]["resolution_scale"])
    expected = _preset_values(name)
    expected.pop("resolution_scale")
    assert values == expected
    assert s.preset == name  # setting the fields itself does not switch back to Custom


def test_custom_leaves_the_fields_alone(addon):
    s = addon.gsgs
    name = PRESET_NAMES[-1]
    _off_preset(s, name)
    before = _field_values(s)
    s.preset = "custom"
    assert _field_values(s) == before
    s.preset = name
    chosen = _field_values(s)
    s.preset = "custom"
    assert _field_values(s) == chosen


@pytest.mark.parametrize("field", list(FIELDS))
def test_editing_a_field_away_from_the_preset_makes_it_custom(addon, field):
    s = addon.gsgs
    name = PRESET_NAMES[0]
    s.preset = name
    setattr(s, field, getattr(s, field))  # the same value: still the preset
    assert s.preset == name
    other = {"iterations": s.iterations + 1, "rounds": (s.rounds + 1) % 20,
             "resolution_scale": 0.5 if s.resolution_scale != 0.5 else 0.25, "max_side": s.max_side + 16,
             "generator": "warp" if s.generator != "warp" else "depth"}[field]
    setattr(s, field, other)
    assert s.preset == "custom" and getattr(s, field) == pytest.approx(other)


def _engine_configs(settings: dict):
    from gsgs_engine.priors.config import prior_config_from_settings
    from gsgs_engine.reconstruct import config_from_settings

    return config_from_settings(settings), prior_config_from_settings(settings)


def _preset_configs(name: str):
    from gsgs_engine.priors.config import PriorConfig
    from gsgs_engine.train.trainer import TrainConfig

    tc, pc, _, _ = apply_preset((TrainConfig(), PriorConfig()), name=name)
    return tc, pc


@pytest.mark.parametrize("name", PRESET_NAMES)
def test_jobs_written_by_the_addon_carry_the_preset_and_read_as_apply_preset(addon, tmp_path, name):
    from gsgs_blender.ops_train import job_settings

    s = addon.gsgs
    s.preset = name
    settings = job_settings(bpy.context)
    p = PRESETS[name]
    assert settings["preset"] == name
    assert settings["iters"] == p["iters"] and settings["prior"] == p["prior"]
    assert settings["resolution_scale"] == pytest.approx(p["resolution_scale"])
    assert settings["max_side"] == p["max_side"]
    assert settings["prior_settings"]["rounds"] == p["rounds"]
    assert settings["prior_settings"]["num_pseudo"] == max(p["pseudo_views"], 1)
    if p["sh_degree"] != "auto":
        assert settings["sh_degree"] == int(p["sh_degree"])

    # the validate operator writes a job folder with the same settings; the engine reads them as the preset
    s.validate_source = str(tmp_path)
    assert bpy.ops.gsgs.validate() == {"FINISHED"}
    spec = json.loads((Path(bpy.path.abspath(s.validate_job)) / "job.json").read_text())
    assert spec["settings"] == json.loads(json.dumps(settings))
    assert _engine_configs(spec["settings"]) == _preset_configs(name)


def test_custom_jobs_have_no_preset(addon):
    from gsgs_blender.ops_train import job_settings

    addon.gsgs.preset = PRESET_NAMES[0]
    addon.gsgs.preset = "custom"
    assert "preset" not in job_settings(bpy.context)


@pytest.mark.parametrize("name", PRESET_NAMES)
def test_engine_reads_a_bare_preset_job_as_apply_preset(tmp_path, name):
    job = Job.create(tmp_path / "job", "train", data={"path": "x"}, settings={"preset": name})
    settings = Job.open(job.root).spec["settings"]
    assert _engine_configs(settings) == _preset_configs(name)
    resolved = settings_with_preset(settings)
    assert resolved["resolution_scale"] == PRESETS[name]["resolution_scale"]  # what run_train_job loads at
    assert resolved["max_side"] == PRESETS[name]["max_side"]  # ... and the size cap it loads with
    assert resolved["prior"] == PRESETS[name]["prior"]  # what run_train_job branches on


def test_explicit_job_settings_win_over_the_preset():
    name = PRESET_NAMES[0]
    p = PRESETS[name]
    settings = {"preset": name, "iters": p["iters"] + 5, "sh_degree": 1, "prior": "warp",
                "prior_settings": {"rounds": p["rounds"] + 2}}
    tc, pc = _engine_configs(settings)
    assert (tc.iters, tc.sh_degree, pc.prior, pc.rounds) == (p["iters"] + 5, 1, "warp", p["rounds"] + 2)
    assert pc.num_pseudo == max(p["pseudo_views"], 1) and tc.backend == p["backend"]
    assert settings_with_preset(settings_with_preset(settings)) == settings_with_preset(settings)


def test_unknown_preset_is_refused_by_name():
    from gsgs_engine import GsgsError

    with pytest.raises(GsgsError, match="choose one of"):
        _engine_configs({"preset": "nonsense"})
