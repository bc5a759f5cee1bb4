from __future__ import annotations

import numpy as np
import pytest

from specsynth.spec.models import Augment
from specsynth.views.augment import augment, draw


@pytest.fixture
def img():
    rng = np.random.default_rng(0)
    base = rng.integers(40, 216, size=(24, 32, 3), dtype=np.uint8)
    base[:4, :4] = 128  # a grey patch, for the hue test
    return base


def test_identity_when_all_zero(img):
    out = augment(img, Augment(), np.random.default_rng(1))
    assert np.array_equal(out, img)


def test_rejects_non_uint8_rgb():
    with pytest.raises(ValueError):
        augment(np.zeros((4, 4, 3), np.float32), Augment(), np.random.default_rng(0))
    with pytest.raises(ValueError):
        augment(np.zeros((4, 4), np.uint8), Augment(), np.random.default_rng(0))


FULL = Augment(brightness=0.3, contrast=0.3, hue=0.1, saturation=0.4, noise_std=0.03, blur_sigma=(0.5, 1.5))


def test_deterministic_and_seed_dependent(img):
    a = augment(img, FULL, np.random.default_rng(7))
    b = augment(img, FULL, np.random.default_rng(7))
    c = augment(img, FULL, np.random.default_rng(8))
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    assert a.dtype == np.uint8 and a.shape == img.shape
    assert not np.shares_memory(a, img)


@pytest.mark.parametrize("seed", range(20))
def test_drawn_parameters_within_ranges(seed):
    p = draw(FULL, np.random.default_rng(seed))
    assert 0.7 <= p["brightness"] <= 1.3
    assert 0.7 <= p["contrast"] <= 1.3
    assert 0.6 <= p["saturation"] <= 1.4
    assert -0.1 <= p["hue"] <= 0.1
    assert 0.5 <= p["blur_sigma"] <= 1.5


def test_draw_count_independent_of_enabled_augmentations():
    # Enabling one augmentation must not change another's draw for the same seed.
    a = draw(Augment(brightness=0.2), np.random.default_rng(3))
    b = draw(Augment(brightness=0.2, hue=0.3, blur_sigma=(1.0, 2.0)), np.random.default_rng(3))
    assert a["brightness"] == b["brightness"]


@pytest.mark.parametrize("seed", range(10))
def test_brightness_only_scales_within_range(img, seed):
    out = augment(img, Augment(brightness=0.2), np.random.default_rng(seed))
    ratio = out.astype(float).mean() / img.astype(float).mean()
    assert 0.8 - 0.01 <= ratio <= 1.2 + 0.01


def test_hue_keeps_greys_and_luminance(img):
    out = augment(img, Augment(hue=0.5), np.random.default_rng(2))
    assert np.abs(out[:4, :4].astype(int) - 128).max() <= 1
    assert abs(out.astype(float).mean() - img.astype(float).mean()) < 2.0


def test_zero_saturation_range_endpoint_makes_grey():
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, size=(8, 8, 3), dtype=np.uint8)
    # saturation 1.0 can draw a factor near 0; find a seed that does and check channels converge.
    for seed in range(200):
        if draw(Augment(saturation=1.0), np.random.default_rng(seed))["saturation"] < 0.05:
            out = augment(img, Augment(saturation=1.0), np.random.default_rng(seed)).astype(int)
            spread = (out.max(axis=-1) - out.min(axis=-1)).mean()
            assert spread < 0.1 * (img.max(axis=-1).astype(int) - img.min(axis=-1)).mean()
            return
    pytest.fail("no seed drew a near-zero saturation factor")


def test_noise_strength(img):
    flat = np.full((64, 64, 3), 128, np.uint8)
    out = augment(flat, Augment(noise_std=0.04), np.random.default_rng(0)).astype(float)
    assert abs(out.std() - 0.04 * 255) < 0.5
    assert abs(out.mean() - 128) < 0.5


def test_blur_smooths_and_keeps_mean(img):
    out = augment(img, Augment(blur_sigma=(2.0, 2.0)), np.random.default_rng(0))
    assert out.astype(float).std() < 0.7 * img.astype(float).std()
    assert abs(out.astype(float).mean() - img.astype(float).mean()) < 1.5
