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
    draw = np.random.default_rng(0)
    draw.random()  # the centring draw (centre_p 0: never centred)
    y0, x0 = int(draw.integers(512 - 256 + 1)), int(draw.integers(512 - 256 + 1))
    # THEN both have the crop's size, and the zoomed one is the whole image shrunk by 2 (area-averaged), its labels
    # by nearest neighbour: the same states, no value between them, the patch a quarter of its area
    assert rgb.shape == (256, 256, 3) and lab.shape == (256, 256) and rgb1.shape == (256, 256, 3)
    assert np.array_equal(rgb, cv2.resize(it.rgb, (256, 256), interpolation=cv2.INTER_AREA))
    assert set(np.unique(lab)) == {0, 2}
    assert (lab == 2).sum() == (it.states == 2).sum() // 4
    # AND zoom 1 is the plain crop: the 256 px window the same draws place, labels untouched
    assert np.array_equal(rgb1, it.rgb[y0:y0 + 256, x0:x0 + 256]) and np.array_equal(lab1, it.states[y0:y0 + 256, x0:x0 + 256])


def test_zoom_beyond_a_small_image_reflects_its_border():
    it = _item(300, 300)
    # a 3x zoom of a 256 px crop needs a 768 px region of a 300 px image: reflected, then shrunk
    rgb, lab = ot._crop(it, 256, np.random.default_rng(1), centre_p=1.0, zoom=3.0)
    assert rgb.shape == (256, 256, 3) and lab.shape == (256, 256)
    # the reflected copies of the patch appear more than once in the shrunk crop
    n, _ = cv2.connectedComponents((lab == 2).astype(np.uint8))
    assert n - 1 >= 2


def test_the_training_defaults_are_the_recipe_recorded_in_the_shipped_default():
    import dataclasses

    from inspect_pipe.saliency_defects import _onnx_detect as od

    # the training command (its defaults) reproduces the shipped network: every setting recorded in its metadata
    recorded = od.load_onnx_model(od.default_onnx_path()).meta["training"]["config"]
    defaults = {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(ot.OnnxTrainConfig()).items()}
    assert recorded == defaults
    assert defaults["zoom_out_p"] == 0.5 and defaults["zoom_out_max"] == 3.0 and defaults["arch"] == "effnet_lite1_unet"


def test_the_states_network_is_the_default_recipe_with_the_step_limit_its_command_names():
    import dataclasses

    from inspect_pipe.saliency_defects import _onnx_detect as od

    # v6's recorded settings are the training defaults but for the step limit, and its recorded command gives that limit
    meta = od.load_onnx_model(od.condition_state_onnx_path()).meta["training"]
    defaults = {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(ot.OnnxTrainConfig()).items()}
    assert {k: v for k, v in meta["config"].items() if k != "max_steps"} == {k: v for k, v in defaults.items() if k != "max_steps"}
    assert f"--max-steps {meta['config']['max_steps']}" in meta["command"] and meta["config"]["max_steps"] != defaults["max_steps"]


def test_refit_attached_keeps_the_states_networks_offsets_true_to_each_shipped_file(tmp_path, monkeypatch):
    from inspect_pipe.saliency_defects import _onnx_detect as od

    # GIVEN a package folder with the states network (v6) and two deciders, and a network elsewhere
    pkg = tmp_path / "models"
    pkg.mkdir()
    for v in (1, 5, 6):
        (pkg / f"defects_unet_v{v}.onnx").write_bytes(b"net")
    monkeypatch.setattr(od, "condition_state_onnx_path", lambda: pkg / "defects_unet_v6.onnx")
    monkeypatch.setattr(ot, "_read_meta", lambda p: {"severity": {}})
    calls = []
    monkeypatch.setattr(ot, "set_attached_bias", lambda s, d, scale, **kw: calls.append((s.name, d.name, scale)) or {})
    # WHEN the states network is exported THEN its offsets are fitted for every other shipped network at STATES_SCALE
    ot.refit_attached(pkg / "defects_unet_v6.onnx", val={"corrosion": []})
    assert calls == [("defects_unet_v6.onnx", "defects_unet_v1.onnx", od.STATES_SCALE),
                     ("defects_unet_v6.onnx", "defects_unet_v5.onnx", od.STATES_SCALE)]
    # WHEN a shipped decider is exported again THEN the states network's offsets are fitted again for that file only
    calls.clear()
    ot.refit_attached(pkg / "defects_unet_v5.onnx", val={"corrosion": []})
    assert calls == [("defects_unet_v6.onnx", "defects_unet_v5.onnx", od.STATES_SCALE)]
    # AND a network written elsewhere (a trial) changes nothing in the package
    calls.clear()
    (tmp_path / "trial.onnx").write_bytes(b"net")
    assert ot.refit_attached(tmp_path / "trial.onnx", val={"corrosion": []}) == [] and calls == []
