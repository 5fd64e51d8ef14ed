"""End to end through the scripts on a tiny generated pairs manifest: train -> infer -> evaluate."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lightcrafter.io import display_to_linear, write_jsonl, write_rgb_exr
from lightcrafter.refiner.toy import toy_pair

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def _write_clip(folder: Path, video):  # (3, N, H, W) in [-1, 1] -> linear EXR frames
    disp = ((video.numpy().transpose(1, 2, 3, 0) + 1) / 2).clip(0, 1)
    for i, f in enumerate(disp):
        write_rgb_exr(folder / f"{i:04d}.exr", display_to_linear(f))


def _run(*args, cwd):
    r = subprocess.run([sys.executable, *map(str, args)], cwd=cwd, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    return r


@pytest.mark.slow
def test_train_infer_evaluate(tmp_path):
    """Selection on a validation scene carved from train, baselines, strips, evaluation of every method."""
    import torch

    recs = []
    for i, (scene, split) in enumerate([("a", "train"), ("a", "train"), ("b", "train"), ("c", "test")]):
        p = toy_pair(i, num_frames=5)
        _write_clip(tmp_path / f"p{i}/proxy", p["proxy"])
        _write_clip(tmp_path / f"p{i}/target", p["target"])
        recs.append({"pair_id": f"p{i}", "kind": "synthetic", "scene_id": scene, "proxy": f"p{i}/proxy",
                     "target": f"p{i}/target", "num_frames": 5, "width": 48, "height": 32, "split": split})
    recs[3]["source"] = "p3/target"  # an input video for the strip's first column
    write_jsonl(tmp_path / "pairs.jsonl", recs)
    cfg = {"model": {"ae_coeffs": [8, 4, 4]}, "train": {"max_steps": 2, "grad_accum": 2},
           "infer": {"num_steps": 4},
           "select": {"val_scenes": 1, "checkpoints": [1], "strengths": [0.0, 0.5], "guidance_scales": [1.0],
                      "max_val_pairs": 1},
           "baselines": {"regressor_steps": 2, "affine_colour": True}}
    _run(SCRIPTS / "train_refiner.py", "--pairs", "pairs.jsonl", "--config-json", json.dumps(cfg), "--out", "m",
         "--threads", "1", cwd=tmp_path)
    assert (tmp_path / "m/model.pt").is_file() and (tmp_path / "m/train.log").is_file()
    sel = json.loads((tmp_path / "m/selection.json").read_text())
    # candidate steps x (strengths x guidance scales with the transformer, + the anchor alone once: it ignores both)
    assert len(sel["selection"]["table"]) == 2 * (2 * 1 + 1)
    assert {r["residual_scale"] for r in sel["selection"]["table"]} == {0.0, 1.0}
    assert sel["carve"]["val_groups"] in (["a"], ["b"]) and "p3" not in sel["fit_pairs"] + sel["val_pairs"]
    chosen = sel["selection"]["chosen"]
    st = torch.load(tmp_path / "m/model.pt", weights_only=False)
    assert st["config"]["infer"]["strength"] == chosen["strength"] and set(st["baselines"]) == {"regressor",
                                                                                                  "affine_colour"}
    # the workflow passes its infer section; the validation choice still applies (num_steps overridden)
    _run(SCRIPTS / "infer_refiner.py", "--model", "m/model.pt", "--pairs", "pairs.jsonl", "--out", "r",
         "--config-json", json.dumps({"infer": {"num_steps": 2, "strength": 1.0}}), "--threads", "1", cwd=tmp_path)
    man = json.loads((tmp_path / "r/manifest.json").read_text())
    assert [e["pair_id"] for e in man["pairs"]] == ["p3"] and (tmp_path / "r/p3/0004.exr").is_file()
    assert man["infer"]["strength"] == chosen["strength"] and man["infer"]["num_steps"] == 2
    e = man["pairs"][0]
    assert e["strip_columns"] == ["input", "proxy", "refined", "target"] and (tmp_path / e["strip"]).is_file()
    assert (tmp_path / "r/baselines/regressor/p3/0004.exr").is_file()
    _run(SCRIPTS / "evaluate_refiner.py", "--pairs", "pairs.jsonl", "--refined", "r/manifest.json",
         "--out", "eval/metrics.json", cwd=tmp_path)
    m = json.loads((tmp_path / "eval/metrics.json").read_text())
    assert m["num_pairs"] == 1 and m["ae_round_trip_psnr_db_mean"] > 20
    assert m["methods"] == ["proxy", "refined", "affine_colour", "regressor"]
    for k in m["methods"]:
        assert np.isfinite(m["mean"][k]["psnr_db"]) and 0 < m["mean"][k]["ssim"] <= 1
    d = m["vs_proxy"]["refined"]["psnr_db"]
    assert d["n"] == 1 and d["low"] is None and d["high"] is None and d["too_few"].startswith("too few clips")
    assert d["mean"] == pytest.approx(m["mean"]["refined"]["psnr_db"] - m["mean"]["proxy"]["psnr_db"])
    # a benchmark of zero clips (no pair in the split asked for): one line naming the manifest, nothing written
    for script, task, args in (("infer_refiner.py", "refine", ["--model", "m/model.pt", "--out", "r_val"]),
                               ("evaluate_refiner.py", "evaluate", ["--refined", "r/manifest.json", "--out",
                                                                    "r_val/metrics.json"])):
        r = subprocess.run([sys.executable, str(SCRIPTS / script), "--pairs", "pairs.jsonl", "--split", "val", *args],
                           cwd=tmp_path, capture_output=True, text=True)
        last = r.stderr.strip().splitlines()[-1]
        assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr[-2000:]
        assert last == (f"{script[:-3]}: pairs.jsonl: no pairs with split == 'val' to {task} (the manifest has "
                        "test: 1, train: 3); pass the split it has, or rebuild it with clips in that split")
        assert not (tmp_path / "r_val").exists()


def test_train_script_fails_clearly_without_train_pairs(tmp_path):
    write_jsonl(tmp_path / "pairs.jsonl", [{"pair_id": "a", "proxy": "x", "target": "y", "num_frames": 5,
                                            "width": 16, "height": 16, "split": "test"}])
    r = subprocess.run([sys.executable, str(SCRIPTS / "train_refiner.py"), "--pairs", "pairs.jsonl", "--out", "m"],
                       cwd=tmp_path, capture_output=True, text=True)
    assert r.returncode == 1 and "no pairs with split == 'train'" in r.stderr


def test_a_nan_in_a_proxy_frame_stops_training_in_one_line_naming_the_frame(tmp_path):
    from lightcrafter.io import read_rgb_exr

    recs = []
    for i in range(2):
        p = toy_pair(i, num_frames=5)
        _write_clip(tmp_path / f"p{i}/proxy", p["proxy"])
        _write_clip(tmp_path / f"p{i}/target", p["target"])
        recs.append({"pair_id": f"p{i}", "kind": "synthetic", "scene_id": f"s{i}", "proxy": f"p{i}/proxy",
                     "target": f"p{i}/target", "num_frames": 5, "width": 48, "height": 32, "split": "train"})
    write_jsonl(tmp_path / "pairs.jsonl", recs)
    bad = tmp_path / "p0/proxy/0002.exr"
    frame = read_rgb_exr(bad)
    frame[3, 5] = np.nan
    write_rgb_exr(bad, frame)
    cfg = {"model": {"ae_coeffs": [8, 4, 4]}, "train": {"max_steps": 1}, "select": {"val_scenes": 0},
           "baselines": {"regressor_steps": 0, "affine_colour": False}}
    r = subprocess.run([sys.executable, str(SCRIPTS / "train_refiner.py"), "--pairs", "pairs.jsonl", "--config-json",
                        json.dumps(cfg), "--out", "m", "--threads", "1"], cwd=tmp_path, capture_output=True, text=True)
    last = r.stderr.strip().splitlines()[-1]
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr[-2000:]
    assert last.startswith("train_refiner: ") and \
        last.endswith("p0/proxy/0002.exr: 1 pixel(s) with NaN/Inf radiance; re-render this frame")
    assert not (tmp_path / "m/model.pt").exists()


@pytest.mark.slow
def test_scale_benchmark_keeps_validation_fixed_while_data_and_model_size_vary(tmp_path):
    """benchmarks/refiner_scale.py: one fit per (blocks, fit groups), candidates per step, the same validation
    clips in every fit, and the test split never read (its folders do not exist)."""
    recs = []
    for i, scene in enumerate("abcd"):
        p = toy_pair(i, num_frames=5)
        _write_clip(tmp_path / f"p{i}/proxy", p["proxy"])
        _write_clip(tmp_path / f"p{i}/target", p["target"])
        recs.append({"pair_id": f"p{i}", "kind": "synthetic", "scene_id": scene, "proxy": f"p{i}/proxy",
                     "target": f"p{i}/target", "num_frames": 5, "width": 48, "height": 32, "split": "train"})
    recs.append({**recs[0], "pair_id": "t0", "scene_id": "e", "proxy": "missing/proxy", "target": "missing/target",
                 "split": "test"})
    write_jsonl(tmp_path / "pairs.jsonl", recs)
    cfg = {"model": {"ae_coeffs": [8, 4, 4]}, "infer": {"num_steps": 2},
           "select": {"val_scenes": 1, "strengths": [0.5], "guidance_scales": [1.0], "max_val_pairs": 1,
                      "correction_blurs_px": [0.0, 2.0]}}
    bench = Path(__file__).resolve().parents[1] / "benchmarks" / "refiner_scale.py"
    _run(bench, "--pairs", "pairs.jsonl", "--config-json", json.dumps(cfg), "--layers", "1", "2", "--fit-groups", "1",
         "0", "--max-steps", "2", "--steps", "1", "--out", "scale.json", cwd=tmp_path)
    res = json.loads((tmp_path / "scale.json").read_text())
    runs = res["runs"]
    assert [(r["layers"], r["fit_groups"]) for r in runs] == [(1, 1), (1, 3), (2, 1), (2, 3)]
    assert len({json.dumps(r["val_pairs"]) for r in runs}) == 1 and len(runs[0]["val_pairs"]) == 1
    assert runs[0]["val_groups"] == runs[1]["val_groups"] and runs[0]["fit_pairs"] == 1 and runs[1]["fit_pairs"] == 3
    assert runs[2]["transformer_parameters"] > runs[0]["transformer_parameters"]
    assert len(res["points"]) == 4 * 2  # steps 1 and 2 of every fit
    for r in runs:
        assert [s["step"] for s in r["steps"]] == [1, 2]
        for s in r["steps"]:
            assert s["correction_blur_px"] in (0.0, 2.0) and s["correction_blur_frames"] == 0.0  # from the grid
            assert s["val_refined_minus_proxy_db"] == pytest.approx(s["val_refined_psnr_db"] - r["val_proxy_psnr_db"],
                                                                    abs=2e-3)
            assert np.isfinite(s["fit_refined_minus_proxy_db"]) and np.isfinite(s["val_anchor_psnr_db"])


def test_benchmarks_read_a_study_configs_refiner_through_its_extends_chain():
    """benchmarks/refiner_scale.py --config config/study.yaml: the study file holds only what it changes, so its
    refiner is config.yaml's with the study's keys over it, not the library's defaults with the study's keys."""
    import yaml

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from refiner_small_scale import _cfg_from_yaml

    repo = Path(__file__).resolve().parents[1]
    default = yaml.safe_load((repo / "config/config.yaml").read_text())["refiner"]
    study = yaml.safe_load((repo / "config/study.yaml").read_text())["refiner"]
    cfg = _cfg_from_yaml(repo / "config/study.yaml", {"infer": {"num_steps": 3}})
    assert cfg["train"]["max_steps"] == study["train"]["max_steps"] != default["train"]["max_steps"]
    assert cfg["select"]["strengths"] == default["select"]["strengths"]  # config.yaml's, not in study.yaml
    assert cfg["select"]["correction_blurs_frames"] == study["select"]["correction_blurs_frames"]
    assert cfg["infer"]["num_steps"] == 3
