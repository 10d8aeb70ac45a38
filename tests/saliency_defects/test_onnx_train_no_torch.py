"""Training side of the onnx engine that needs no PyTorch (numpy, OpenCV, typer): the split rules,
the severity targets of a batch, the condition-state F1, the degradation augmentation and the
training command's refusal of missing data. They run under `make test` (the [train] extra, with
PyTorch and onnx, is not installed there); the rest is in test_onnx_train.py."""

import numpy as np

from inspect_pipe.saliency_defects import _onnx_detect as od
from inspect_pipe.saliency_defects import _onnx_train as ot
from inspect_pipe.saliency_defects._datasets import split_of

from ._synth import tiny_items as _tiny_items


def test_validation_images_are_a_part_of_train_never_eval():
    stems = [f"{i:03d}" for i in range(300)]
    for set_name in ("crackforest", "vt_corrosion_cs", "sd_saliency_900"):
        train = [s for s in stems if split_of(set_name, s) == "train"]
        val = [s for s in train if ot.is_val(set_name, s)]
        assert 0.1 < len(val) / len(train) < 0.3
        assert all(split_of(set_name, s) == "train" for s in val)


def test_cli_train_onnx_without_the_three_sets_exits_2(tmp_path):
    from typer.testing import CliRunner

    from cli.main import app

    (tmp_path / "crackforest").mkdir()
    r = CliRunner().invoke(app, ["detect", "train", str(tmp_path), "--engine", "onnx", "-o", str(tmp_path / "m.onnx")])
    assert r.exit_code == 2
    line = r.output.strip().splitlines()[-1]
    assert "vt_corrosion_cs" in line and "sd_saliency_900" in line and not (tmp_path / "m.onnx").exists()


def test_severity_targets_only_on_labelled_corrosion_pixels():
    # GIVEN tiny items where the corrosion ones carry condition states 1..3 on their GT pixels
    items = _tiny_items(3)
    for k, it in enumerate(items["corrosion"]):
        it.states = (it.gt.astype(np.uint8) * (1 + k % 3))
    cfg = ot.OnnxTrainConfig(crop_px=32, per_class_batch=2)
    x, y, c, sev = ot._batch(items, cfg, np.random.default_rng(0))
    corr = c == od.CLASSES.index("corrosion")
    # THEN crack and surface samples have no severity target, corrosion samples state - 1 on GT only
    assert (sev[~corr] == ot.IGNORE).all()
    for i in np.flatnonzero(corr):
        on = y[i] > 0
        assert (sev[i][~on] == ot.IGNORE).all() and set(np.unique(sev[i][on])) <= {0, 1, 2}


def test_state_confusion_and_f1_by_hand():
    from inspect_pipe.saliency_defects._metrics import state_confusion, state_f1

    gt = np.array([[0, 1, 1, 2], [2, 3, 3, 0]], np.uint8)
    pred = np.array([[0, 1, 2, 2], [2, 3, 0, 0]], np.uint8)
    conf = state_confusion(pred, gt)
    assert conf.sum() == 8 and conf[1, 1] == 1 and conf[1, 2] == 1 and conf[3, 0] == 1
    f1 = state_f1(conf)
    # fair: tp 1, pred 1, gt 2 -> 2/3; poor: tp 2, pred 3, gt 2 -> 4/5; severe: tp 1, pred 1, gt 2 -> 2/3
    assert np.allclose(f1[1:], [2 / 3, 4 / 5, 2 / 3])


def test_degradation_keeps_the_geometry_and_leaves_the_recipe_alone_when_off():
    import cv2

    # GIVEN a crop with one sharp square and its label
    rgb = np.full((96, 96, 3), 60, np.uint8)
    rgb[30:60, 40:70] = (200, 90, 40)
    lab = np.zeros((96, 96), np.uint8)
    lab[30:60, 40:70] = 1
    # WHEN it is degraded as a drone camera and the mosaic would
    outs = [ot._degrade(rgb, np.random.default_rng(s)) for s in range(20)]
    # THEN the image keeps its size and type, the square stays where its label is (the label stays valid) ...
    for o in outs:
        assert o.shape == rgb.shape and o.dtype == np.uint8
        inside, outside = o[35:55, 45:65].mean(axis=(0, 1)), o[:20, :20].mean(axis=(0, 1))
        assert inside[0] > outside[0] + 80
    # ... and it is degraded: softer edges on average (resampling, blur, JPEG)
    edge = lambda im: float(np.abs(cv2.Sobel(cv2.cvtColor(im, cv2.COLOR_RGB2GRAY), cv2.CV_32F, 1, 0)).max())  # noqa: E731
    assert np.mean([edge(o) for o in outs]) < 0.8 * edge(rgb)
    # AND the training's augmentation applies it at degrade_p 1 (same draws otherwise: same turn and flip of the label)
    a = ot._augment(rgb, lab, np.random.default_rng(5))
    b = ot._augment(rgb, lab, np.random.default_rng(5), 1.0)
    assert np.array_equal(a[1], b[1]) and not np.allclose(a[0], b[0], atol=0.02)
