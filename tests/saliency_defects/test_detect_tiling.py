"""Tiled processing gives the whole-image result away from tile borders, with bounded memory."""

import numpy as np
import pytest

from inspect_pipe.saliency_defects import class_probabilities_u8, compute_features, default_model_path, detect, load_model
from inspect_pipe.saliency_defects._features import check_image

from ._synth import painted_wall_with_rust, pavement_with_cracks


@pytest.fixture(scope="module")
def model():
    return load_model(default_model_path())


@pytest.fixture(scope="module")
def big_image():
    # a 1000 x 1400 "mosaic": rusty wall on the left, cracked surface on the right
    rng = np.random.default_rng(5)
    a, _ = painted_wall_with_rust(rng, 1000, 700, n_blobs=12)
    b, _ = pavement_with_cracks(rng, 1000, 700, n_cracks=8)
    return np.ascontiguousarray(np.hstack([a, b]))


def test_tiles_match_whole_image(model, big_image):
    # GIVEN one image processed whole and in 256 px tiles (35 tiles, each with its margin)
    whole = class_probabilities_u8(big_image, model, ("corrosion", "crack"), tile_px=2048)
    tiled = class_probabilities_u8(big_image, model, ("corrosion", "crack"), tile_px=256)
    for k in ("corrosion", "crack"):
        # THEN the probabilities agree to one grey level almost everywhere
        d = np.abs(whole[k].astype(int) - tiled[k].astype(int))
        assert (d <= 1).mean() > 0.999, (k, (d <= 1).mean(), d.max())
        assert np.percentile(d, 99.99) <= 2


def test_tiled_decisions_match(model, big_image):
    a = detect(big_image, model, tile_px=2048)
    b = detect(big_image, model, tile_px=384)
    assert (a.mask == b.mask).mean() > 0.999
    assert abs(len(a.regions) - len(b.regions)) <= max(2, len(a.regions) // 20)


def test_features_are_local():
    # a change far away does not change a pixel's features (fixed normalisation, no global stats)
    rng = np.random.default_rng(2)
    img, _ = pavement_with_cracks(rng, 512, 1024)
    img2 = img.copy()
    img2[:, 768:] = 255 - img2[:, 768:]
    f1, f2 = compute_features(img), compute_features(img2)
    assert np.allclose(f1.data[:, :, :200], f2.data[:, :, :200], atol=1e-4)


@pytest.mark.parametrize(
    "bad",
    [np.zeros((0, 0, 3), np.uint8), np.zeros((20, 20, 3), np.uint16), np.zeros((20, 20, 2), np.uint8)],
)
def test_bad_arrays_are_refused(bad):
    with pytest.raises(ValueError):
        check_image(bad)


def test_grey_image_refused_for_corrosion_but_fine_for_cracks(model):
    rng = np.random.default_rng(3)
    img, gt = pavement_with_cracks(rng)
    grey = img[:, :, 0].copy()
    with pytest.raises(ValueError, match="needs colour"):
        detect(grey, model, kinds=("corrosion",))
    det = detect(grey, model, kinds=("crack",))
    assert det.mask.any()


def test_half_resolution_features_are_local_and_shared_pyramids_change_nothing():
    rng = np.random.default_rng(6)
    img, _ = painted_wall_with_rust(rng, 512, 1024)
    img2 = img.copy()
    img2[:, 768:] = 255 - img2[:, 768:]
    f1, f2 = compute_features(img, level=1), compute_features(img2, level=1)
    assert f1.shape == (256, 512)
    # columns 0..99 at level 1 are image columns 0..199, far from the change at 768
    assert np.allclose(f1.data[:, :, :100], f2.data[:, :, :100], atol=1e-4)
    # computing both levels with one shared pyramid gives what separate calls give (to float32
    # rounding: 'coh' comes out up to 3e-8 apart in about a third of repeated identical calls, with
    # one OpenCV thread too, so bit equality is not a property of the features)
    shared: dict = {}
    g0 = compute_features(img, ("int_cs", "ori_cs", "coh"), level=0, shared=shared)
    g1 = compute_features(img, ("int_cs", "ori_cs", "lab_a_mean"), level=1, shared=shared)
    assert np.allclose(g0.data, compute_features(img, ("int_cs", "ori_cs", "coh")).data, rtol=0, atol=1e-6)
    assert np.allclose(g1.data, compute_features(img, ("int_cs", "ori_cs", "lab_a_mean"), level=1).data, rtol=0, atol=1e-6)


def test_colour_statistics_read_texture_and_colour_relative_to_the_surroundings():
    # GIVEN an even grey-green wall with one mottled rust patch (orange and dark brown mixed at
    # random, rows and columns 384..447)
    rng = np.random.default_rng(9)
    img = np.full((512, 512, 3), (110, 128, 112), np.uint8)
    mix = rng.random((64, 64, 1)).astype(np.float32)
    patch = mix * np.array([40, 90, 170], np.float32) + (1 - mix) * np.array([30, 50, 90], np.float32)
    img[384:448, 384:448] = np.clip(patch, 0, 255).astype(np.uint8)
    names = ("lab_a_std7", "val_std15", "rchrom_grad15", "lab_a_rel", "val_rel", "ctex_r", "ctex_v", "ctex2_v")
    # WHEN the features are computed at half resolution
    f = compute_features(img, names, level=1)
    # THEN on the paint beyond their reach from the patch (level-1 rows and columns 0..15) the
    # variation and texture features are 0 and the colour equals its surroundings' (value ratio
    # v / (v + 0.05)); inside the patch (200..215) variation and texture are positive and a* is
    # above its surroundings' mean
    far, inside = np.s_[0:16, 0:16], np.s_[200:216, 200:216]
    for n in ("lab_a_std7", "val_std15", "rchrom_grad15", "ctex_r", "ctex_v", "ctex2_v"):
        assert np.abs(f[n][far]).max() < 1e-3, n
        assert f[n][inside].min() > 1e-3, n
    v = 128 / 255
    assert np.abs(f["lab_a_rel"][far]).max() < 1e-3
    assert np.abs(f["val_rel"][far] - v / (v + 0.05)).max() < 1e-3
    assert f["lab_a_rel"][inside].mean() > 10
