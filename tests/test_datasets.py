"""Pair manifests: the variant registry, benchmarks, skipped clips, and PairsDataset on generated folders."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lightcrafter import datasets
from lightcrafter.io import DataError, write_json, write_jsonl, write_rgb_exr
from lightcrafter.layout import Layout, root_of
from lightcrafter.refiner import PairsDataset

PLANS = {
    "s0000": {"split": "train", "trajectories": [
        {"id": "t0", "source_light": "L0", "target_lights": ["L1", "L2"]},
        {"id": "t1", "source_light": "L1", "target_lights": ["L0"]}]},
    "s0001": {"split": "test", "trajectories": [{"id": "t0", "source_light": "L2", "target_lights": ["L3"]}]},
    "s0002": {"split": "recon", "trajectories": [{"id": "t0", "source_light": "L0", "target_lights": []}]},
}
REAL = {"bikes_c0": {"split": "train", "video": "bikes.mp4"}, "bikes_c1": {"split": "test", "video": "bikes.mp4"}}
L = Layout("results")


def _frames(folder: Path, n: int, w=32, h=16, value=0.2, skipped=None):
    if skipped:
        write_json(folder.parent / f"{folder.name}.json", {"skipped": skipped})
        return
    for i in range(n):
        write_rgb_exr(folder / f"{i:04d}.exr", np.full((h, w, 3), value * (i + 1), np.float32))
    write_json(folder.parent / f"{folder.name}.json", {"num_frames": n})


def _make_tree(root: Path, n=5):
    specs = [s for v in datasets.VARIANTS for s in datasets.variant_specs(v, L, PLANS, REAL)]
    specs += [s for b in datasets.BENCHMARKS for s in datasets.benchmark_specs(b, L, PLANS, REAL)]
    for s in specs:
        for key, value in (("proxy", 0.1), ("target", 0.2), ("oracle_proxy", 0.15)):
            if key in s and not (root / f"{s[key]}.json").exists():
                _frames(root / s[key], n, value=value)


def test_variants_hold_the_kinds_the_ablation_needs():
    ids = {v: [s["pair_id"] for s in datasets.variant_specs(v, L, PLANS, REAL)] for v in datasets.VARIANTS}
    synth = ["s0000_t0_L1", "s0000_t0_L2", "s0000_t1_L0"]  # train scenes only, every target light; recon left out
    assert ids["no_real"] == synth and ids["clean_buffers"] == synth
    assert ids["no_synthetic"] == ["real_bikes_c0"]
    assert ids["full"] == synth + ["real_bikes_c0"]
    clean = datasets.variant_specs("clean_buffers", L, PLANS, REAL)[0]
    matched = datasets.variant_specs("no_real", L, PLANS, REAL)[0]
    assert clean["proxy"] == "results/proxy_gt/s0000/t0/L1" and matched["proxy"] == "results/proxy/s0000/t0/L1"
    assert clean["target"] == matched["target"] == "results/gt/s0000/t0/rgb/L1"


def test_benchmarks_are_test_split_and_shared():
    syn = datasets.benchmark_specs("synthetic", L, PLANS, REAL)
    assert [s["pair_id"] for s in syn] == ["s0001_t0_L3"]
    assert syn[0]["proxy"] == "results/proxy/s0001/t0/L3" and syn[0]["oracle_proxy"] == "results/proxy_gt/s0001/t0/L3"
    real = datasets.benchmark_specs("real", L, PLANS, REAL)
    assert [s["pair_id"] for s in real] == ["real_bikes_c1"] and real[0]["target"] == "results/real/bikes_c1/rgb"
    assert all(s["split"] == "test" for s in syn + real)


def test_build_records_and_read_dataset(tmp_path):
    _make_tree(tmp_path)
    recs, summary = datasets.build_records(datasets.variant_specs("full", L, PLANS, REAL), tmp_path, "full")
    assert summary["by_kind"] == {"synthetic": 3, "real": 1} and summary["skipped"] == []
    r = recs[0]
    assert (r["num_frames"], r["width"], r["height"], r["kind"], r["variant"]) == (5, 32, 16, "synthetic", "full")
    write_jsonl(tmp_path / "pairs.jsonl", recs)
    ds = PairsDataset(tmp_path / "pairs.jsonl", "train", root=tmp_path)
    assert len(ds) == 4
    item = ds[0]
    assert item["proxy"].shape == (3, 5, 16, 32) and item["target"].shape == (3, 5, 16, 32)
    assert float(item["proxy"].min()) >= -1 and float(item["target"].max()) <= 1


def test_skipped_clip_is_left_out_and_counted(tmp_path):
    _frames(tmp_path / L.proxy("s0000", "t0", "L1"), 0, skipped="structure from motion registered 2/17 frames")
    _make_tree(tmp_path)
    recs, summary = datasets.build_records(datasets.variant_specs("no_real", L, PLANS, REAL), tmp_path)
    assert [r["pair_id"] for r in recs] == ["s0000_t0_L2", "s0000_t1_L0"]
    assert summary["skipped"] == [{"pair_id": "s0000_t0_L1", "reason": "structure from motion registered 2/17 frames"}]


def test_mismatched_frame_counts_raise(tmp_path):
    _make_tree(tmp_path)
    (tmp_path / "results/gt/s0001/t0/rgb/L3/0004.exr").unlink()
    with pytest.raises(DataError, match="s0001_t0_L3"):
        datasets.build_records(datasets.benchmark_specs("synthetic", L, PLANS, REAL), tmp_path)


def test_missing_manifest_raises(tmp_path):
    _make_tree(tmp_path)
    (tmp_path / "results/proxy/s0000/t0/L1.json").unlink()
    with pytest.raises(DataError, match="manifest missing"):
        datasets.build_records(datasets.variant_specs("no_real", L, PLANS, REAL), tmp_path)


def test_unknown_variant_is_one_line_error():
    with pytest.raises(DataError, match="unknown; use one of"):
        datasets.variant("no_realz")


def test_root_of_layout_paths():
    assert root_of("results/datasets/full/pairs.jsonl", "datasets").as_posix() == "results"
    assert root_of("out/x/benchmarks/real/pairs.jsonl", "benchmarks").as_posix() == "out/x"


def test_build_dataset_script(tmp_path):
    _make_tree(tmp_path, n=1)
    script = Path(__file__).resolve().parents[1] / "scripts" / "build_dataset.py"
    out = tmp_path / "results/datasets/no_real/pairs.jsonl"
    subprocess.run([sys.executable, str(script), "--variant", "no_real", "--plans-json", json.dumps(PLANS),
                    "--real-json", json.dumps(REAL), "--output", "results/datasets/no_real/pairs.jsonl"],
                   cwd=tmp_path, check=True)
    assert len(out.read_text().splitlines()) == 3
    assert json.loads((out.parent / "summary.json").read_text())["by_kind"]["synthetic"] == 3
