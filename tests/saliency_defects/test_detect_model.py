"""Model file format and the training machinery on synthetic data (no shared data needed)."""

import numpy as np
import pytest

from inspect_pipe.saliency_defects import (
    ClassTrainConfig, DefectModel, default_model_path, detect, load_model, save_model, train_class,
)
from inspect_pipe.saliency_defects._metrics import mask_prf

from ._synth import painted_wall_with_rust


def test_shipped_model_is_versioned_and_records_its_training_split():
    m = load_model(default_model_path())
    assert m.meta["format"] == "inspect_pipe.defect_model/1"
    assert m.version == "1"
    assert {"corrosion", "crack"} <= set(m.classes)
    for cls in ("corrosion", "crack"):
        data = m.meta["training_data"][cls]
        assert data["split"] == "train" and "sha1" in data["split_rule"]
        from inspect_pipe.saliency_defects import split_of

        assert all(split_of(data["set"], s) == "train" for s in data["images"])
    assert default_model_path().stat().st_size < 200_000


def test_load_model_rejects_other_files(tmp_path):
    bad = tmp_path / "x.npz"
    np.savez(bad, meta=np.frombuffer(b'{"format": "other/1"}', np.uint8))
    with pytest.raises(ValueError, match="unsupported model format"):
        load_model(bad)
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="not a defect model"):
        load_model(junk)


def test_training_learns_synthetic_rust_and_round_trips(tmp_path):
    # GIVEN six synthetic rusty walls for training and a seventh, unseen one
    rng = np.random.default_rng(1)
    data = [painted_wall_with_rust(rng, 192, 256, n_blobs=3) for _ in range(7)]
    train = [(lambda d=d: d) for d in data[:6]]
    cfg = ClassTrainConfig(cls="corrosion", pos_per_image=400, neg_per_image=400, smooth_sigma_px=1.0, min_area_px=30)
    # WHEN a class is trained, saved and loaded
    cm = train_class(train, cfg, log=lambda *_: None)
    model = DefectModel({"corrosion": cm}, {"version": "test"})
    save_model(model, tmp_path / "m.npz")
    loaded = load_model(tmp_path / "m.npz")
    # THEN it finds the rust of the unseen wall, and the loaded model gives the same map
    img, gt = data[6]
    det = detect(img, loaded, kinds=("corrosion",))
    p, r, f = mask_prf(det.mask, gt)
    assert p > 0.85 and r > 0.85, (p, r)
    det0 = detect(img, model, kinds=("corrosion",))
    assert np.array_equal(det0.prob, det.prob)


def test_half_resolution_class_with_joint_tables_trains_and_round_trips(tmp_path):
    # GIVEN synthetic rusty walls and a class computed at pyramid level 1 with brightness-joint tables
    rng = np.random.default_rng(4)
    data = [painted_wall_with_rust(rng, 192, 256, n_blobs=3) for _ in range(7)]
    train = [(lambda d=d: d) for d in data[:6]]
    feats = ("rg_cs", "hs", "val", "lab_a", "sat_mean", "rough", "coh")
    cfg = ClassTrainConfig(cls="corrosion", features=feats, pos_per_image=400, neg_per_image=400, level=1,
                           context=1, pairs=(("lab_a", "val"), ("rough", "val")), min_area_px=30)
    # WHEN it is trained, saved and loaded
    cm = train_class(train, cfg, log=lambda *_: None)
    assert cm.level == 1 and {"lab_a*val", "rough*val"} <= set(cm.stages[0].names)
    model = DefectModel({"corrosion": cm}, {"version": "test"})
    save_model(model, tmp_path / "m.npz")
    loaded = load_model(tmp_path / "m.npz")
    # THEN the loaded model keeps the level and the joint tables, finds the unseen wall's rust at
    # full resolution, and gives the same map
    assert loaded.classes["corrosion"].level == 1
    assert loaded.classes["corrosion"].stages[0].names == cm.stages[0].names
    img, gt = data[6]
    det = detect(img, loaded, kinds=("corrosion",))
    assert det.prob.shape == gt.shape
    p, r, _ = mask_prf(det.mask, gt)
    assert p > 0.75 and r > 0.85, (p, r)
    assert np.array_equal(detect(img, model, kinds=("corrosion",)).prob, det.prob)
