"""The training crops' zoom-out (v5's recipe): numpy and OpenCV only, so it runs without PyTorch."""

import cv2
import numpy as np

from inspect_pipe.saliency_defects import _onnx_train as ot


def _item(h=512, w=512):
    """A corrosion item: a grey image with a 100 x 60 px patch labelled condition state 2 (poor)."""
    rgb = np.full((h, w, 3), 120, np.uint8)
    rgb[200:300, 100:160] = (150, 80, 40)
    states = np.zeros((h, w), np.uint8)
    states[200:300, 100:160] = 2
    it = ot._Item("corrosion", "synthetic", rgb, states > 0, states=states)
    it.pos = np.argwhere(it.gt).astype(np.int32)
    return it


def test_zoomed_out_crop_is_a_larger_region_shrunk_with_its_labels():
    it = _item()
    # WHEN a 256 px crop is taken at zoom 2 (a 512 px region, the whole image here) and at zoom 1
    rgb, lab = ot._crop(it, 256, np.random.default_rng(0), centre_p=0.0, zoom=2.0)
    rgb1, lab1 = ot._crop(it, 256, np.random.default_rng(0), centre_p=0.0, zoom=1.0)
    # THEN both have the crop's size, and the zoomed one is the whole image shrunk by 2 (area-averaged), its labels
    # by nearest neighbour: the same states, no value between them, the patch a quarter of its area
    assert rgb.shape == (256, 256, 3) and lab.shape == (256, 256) and rgb1.shape == (256, 256, 3)
    assert np.array_equal(rgb, cv2.resize(it.rgb, (256, 256), interpolation=cv2.INTER_AREA))
    assert set(np.unique(lab)) == {0, 2}
    assert (lab == 2).sum() == (it.states == 2).sum() // 4
    # AND zoom 1 is the plain crop (a 256 px window of the image, labels untouched)
    assert (lab1 == 2).sum() <= 100 * 60 and set(np.unique(lab1)) <= {0, 2}


def test_zoom_beyond_a_small_image_reflects_its_border():
    it = _item(300, 300)
    # a 3x zoom of a 256 px crop needs a 768 px region of a 300 px image: reflected, then shrunk
    rgb, lab = ot._crop(it, 256, np.random.default_rng(1), centre_p=1.0, zoom=3.0)
    assert rgb.shape == (256, 256, 3) and lab.shape == (256, 256)
    # the reflected copies of the patch appear more than once in the shrunk crop
    n, _ = cv2.connectedComponents((lab == 2).astype(np.uint8))
    assert n - 1 >= 2


def test_recipe_zooms_out_half_of_the_corrosion_crops_up_to_3x():
    cfg = ot.OnnxTrainConfig()
    assert cfg.zoom_out_p == 0.5 and cfg.zoom_out_max == 3.0
