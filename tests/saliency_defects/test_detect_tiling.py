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
    # computing both levels with one shared pyramid gives what separate calls give
    shared: dict = {}
    g0 = compute_features(img, ("int_cs", "ori_cs", "coh"), level=0, shared=shared)
    g1 = compute_features(img, ("int_cs", "ori_cs", "lab_a_mean"), level=1, shared=shared)
    assert np.array_equal(g0.data, compute_features(img, ("int_cs", "ori_cs", "coh")).data)
    assert np.array_equal(g1.data, compute_features(img, ("int_cs", "ori_cs", "lab_a_mean"), level=1).data)
