"""Depth estimators load from a local folder through the real transformers code path."""

import numpy as np
import pytest
import torch

from gsgs_engine import GsgsError
from gsgs_engine.priors.depth_estimators import load_depth_estimator, save_tiny_dpt


def test_none_means_no_estimator():
    assert load_depth_estimator(None) is None
    assert load_depth_estimator("none") is None


def test_missing_folder_is_a_clear_error(tmp_path):
    with pytest.raises(GsgsError, match="config.json"):
        load_depth_estimator(str(tmp_path))


@pytest.mark.slow
def test_tiny_dpt_folder_predicts_a_finite_map_at_image_size(tmp_path):
    pytest.importorskip("transformers")
    est = load_depth_estimator(str(save_tiny_dpt(tmp_path / "dpt")))
    out = est(torch.rand(37, 51, 3))
    assert out.shape == (37, 51) and torch.isfinite(out).all()
    out_np = est(np.random.rand(8, 8, 3).astype(np.float32))
    assert out_np.shape == (8, 8)
