"""Model file format and the training machinery on synthetic data (no shared data needed)."""

import numpy as np
import pytest

from inspect_pipe.saliency_defects import (
    ClassTrainConfig, DefectModel, default_model_path, detect, load_model, save_model, train_class,
)
from inspect_pipe.saliency_defects._metrics import mask_prf
from inspect_pipe.saliency_defects._model import FeatureTable

from ._synth import painted_wall_with_rust


def test_shipped_model_is_versioned_and_records_its_training_split():
    m = load_model(default_model_path())
    assert m.meta["format"] == "inspect_pipe.defect_model/2"
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


def test_load_model_rejects_a_tree_table_without_its_splits(tmp_path):
    # GIVEN the shipped model with one tree table's split array removed from the file
    with np.load(default_model_path(), allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    split = [k for k in arrays if k.endswith(":split")]
    assert split, "the shipped model has a tree table"
    del arrays[split[0]]
    np.savez(tmp_path / "m.npz", **arrays)
    # THEN loading it is an error naming the damage, not a crash in a later detection
    with pytest.raises(ValueError, match="tree table .* incomplete"):
        load_model(tmp_path / "m.npz")


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


def _walk(split, thr, bins, i):
    """Leaf of pixel i by following the tree one node at a time (the definition)."""
    node = 0
    while node < len(split):
        k = split[node]
        right = k >= 0 and bins[k][i] > thr[node]
        node = 2 * node + 1 + int(right)
    return node - len(split)


def test_tree_table_cells_match_a_node_by_node_walk():
    # GIVEN a depth-4 tree on three inputs' bins, with some nodes that do not split
    rng = np.random.default_rng(7)
    split = rng.integers(-1, 3, 15).astype(np.int16)
    thr = rng.integers(0, 48, 15).astype(np.uint8)
    bins = [rng.integers(0, 60, (20, 30)).astype(np.uint8) for _ in range(3)]
    t = FeatureTable("tree", 0.0, 16.0, np.zeros(16, np.float32), True, tree_inputs=("a", "b", "c"),
                     tree_split=split, tree_thr=thr)
    # WHEN the leaves are computed for the whole map at once
    cells = t.tree_cells(dict(zip("abc", bins)))
    # THEN every pixel lands in the leaf a node-by-node walk reaches
    flat = [b.ravel() for b in bins]
    want = np.array([_walk(split, thr, flat, i) for i in range(600)]).reshape(20, 30)
    assert cells.dtype == np.uint8 and np.array_equal(cells, want)


def test_tree_table_trains_saves_and_needs_the_bins_of_its_stage(tmp_path):
    # GIVEN synthetic rusty walls and a class whose first stage has a depth-4 tree table
    rng = np.random.default_rng(5)
    data = [painted_wall_with_rust(rng, 192, 256, n_blobs=3) for _ in range(7)]
    train = [(lambda d=d: d) for d in data[:6]]
    feats = ("hs", "val", "lab_a", "lab_b_std7", "rchrom_rel", "ctex_v")
    cfg = ClassTrainConfig(cls="corrosion", features=feats, pos_per_image=400, neg_per_image=400, level=1,
                           tree_depth=4, tree_min_leaf=50, min_area_px=30)
    # WHEN it is trained, saved and loaded
    cm = train_class(train, cfg, log=lambda *_: None)
    tree = cm.stages[0].tables[-1]
    assert tree.name == "tree" and tree.categorical and set(tree.tree_inputs) <= set(feats)
    assert tree.tree_split.shape == (15,) and (tree.tree_split >= 0).any()
    model = DefectModel({"corrosion": cm}, {"version": "test"})
    save_model(model, tmp_path / "m.npz")
    loaded = load_model(tmp_path / "m.npz")
    # THEN the loaded tree is the same, the unseen wall's rust is found, the maps agree
    lt = loaded.classes["corrosion"].stages[0].tables[-1]
    assert lt.tree_inputs == tree.tree_inputs and np.array_equal(lt.tree_split, tree.tree_split)
    assert np.array_equal(lt.tree_thr, tree.tree_thr) and np.array_equal(lt.llr, tree.llr)
    img, gt = data[6]
    det = detect(img, loaded, kinds=("corrosion",))
    p, r, _ = mask_prf(det.mask, gt)
    assert p > 0.75 and r > 0.85, (p, r)
    assert np.array_equal(detect(img, model, kinds=("corrosion",)).prob, det.prob)
    # a tree table alone has no feature map to bin
    with pytest.raises(ValueError, match="single tables"):
        tree.bins_in({})


def test_tree_depth_is_bounded_by_the_table_size():
    with pytest.raises(ValueError, match="tree depth"):
        ClassTrainConfig(cls="corrosion", tree_depth=9)


def test_models_of_format_1_still_load(tmp_path):
    # a model file written before tree tables existed (format /1, same layout otherwise)
    import json

    m = load_model(default_model_path())
    crack = DefectModel({"crack": m.classes["crack"]}, {"version": "old"})
    save_model(crack, tmp_path / "m.npz")
    with np.load(tmp_path / "m.npz") as z:
        arrays = {k: z[k] for k in z.files}
    header = json.loads(bytes(arrays["meta"]).decode())
    header["format"] = "inspect_pipe.defect_model/1"
    arrays["meta"] = np.frombuffer(json.dumps(header).encode(), np.uint8)
    np.savez_compressed(tmp_path / "old.npz", **arrays)
    old = load_model(tmp_path / "old.npz")
    assert old.classes["crack"].stages[0].names == m.classes["crack"].stages[0].names
