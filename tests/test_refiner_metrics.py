"""PSNR / SSIM / temporal difference on display values in [0, 1]."""

import numpy as np
import pytest

from lightcrafter.metrics import psnr_db, ssim, temporal_difference, video_psnr_db


def test_psnr_known_value():
    a = np.zeros((4, 4, 3))
    assert psnr_db(a, a + 0.1) == pytest.approx(20.0)
    assert video_psnr_db(a[None], a[None]) == 100.0


def test_ssim_identity_and_monotone():
    rng = np.random.default_rng(0)
    img = rng.random((32, 32, 3))
    assert ssim(img, img) == pytest.approx(1.0)
    s1 = ssim(img, np.clip(img + rng.normal(0, 0.05, img.shape), 0, 1))
    s2 = ssim(img, np.clip(img + rng.normal(0, 0.2, img.shape), 0, 1))
    assert 1.0 > s1 > s2


def test_temporal_difference():
    v = np.stack([np.full((2, 2, 3), x) for x in (0.0, 0.1, 0.4)])
    assert np.allclose(temporal_difference(v), [0.1, 0.3])
