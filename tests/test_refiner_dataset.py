"""clean_buffers manifest builder and PairsDataset on a tiny generated folder."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lightcrafter.datasets import build_clean_buffers_records, clean_buffers_specs
from lightcrafter.io import DataError, write_json, write_rgb_exr
from lightcrafter.refiner import PairsDataset

PLANS = {
    "s0000": {"split": "train", "trajectories": [
        {"id": "t0", "source_light": "L0", "target_lights": ["L1", "L2"]},
        {"id": "t1", "source_light": "L1", "target_lights": ["L0"]}]},
    "s0001": {"split": "test", "trajectories": [{"id": "t0", "source_light": "L2", "target_lights": ["L3"]}]},
    "s0002": {"split": "recon", "trajectories": [{"id": "t0", "source_light": "L0", "target_lights": ["L1"]}]},
}


def _frames(folder: Path, n: int, w=32, h=16, value=0.2):
    for i in range(n):
        write_rgb_exr(folder / f"{i:04d}.exr", np.full((h, w, 3), value * (i + 1), np.float32))
    write_json(folder.parent / f"{folder.name}.json", {"num_frames": n})


def _make_tree(root: Path, n=5):
    for s in clean_buffers_specs("results", PLANS):
        _frames(root / s["proxy"], n, value=0.1)
        _frames(root / s["target"], n, value=0.2)


def test_specs_skip_recon_and_enumerate_target_lights():
    ids = [s["pair_id"] for s in clean_buffers_specs("results", PLANS)]
    assert ids == ["s0000_t0_L1", "s0000_t0_L2", "s0000_t1_L0", "s0001_t0_L3"]


def test_build_records_and_read_dataset(tmp_path):
    _make_tree(tmp_path)
    recs = build_clean_buffers_records("results", PLANS, root=tmp_path)
    assert [r["split"] for r in recs] == ["train", "train", "train", "test"]
    r = recs[0]
    assert r["proxy"] == "results/proxy_gt/s0000/t0/L1" and r["target"] == "results/gt/s0000/t0/rgb/L1"
    assert (r["num_frames"], r["width"], r["height"], r["kind"]) == (5, 32, 16, "synthetic")
    from lightcrafter.io import write_jsonl

    write_jsonl(tmp_path / "pairs.jsonl", recs)
    ds = PairsDataset(tmp_path / "pairs.jsonl", "test", root=tmp_path)
    assert len(ds) == 1
    item = ds[0]
    assert item["proxy"].shape == (3, 5, 16, 32) and item["target"].shape == (3, 5, 16, 32)
    assert float(item["proxy"].min()) >= -1 and float(item["target"].max()) <= 1


def test_mismatched_frame_counts_raise(tmp_path):
    _make_tree(tmp_path)
    (tmp_path / "results/gt/s0001/t0/rgb/L3/0004.exr").unlink()
    with pytest.raises(DataError, match="s0001_t0_L3"):
        build_clean_buffers_records("results", PLANS, root=tmp_path)


def test_missing_manifest_raises(tmp_path):
    _make_tree(tmp_path)
    (tmp_path / "results/proxy_gt/s0000/t0/L1.json").unlink()
    with pytest.raises(DataError, match="manifest missing"):
        build_clean_buffers_records("results", PLANS, root=tmp_path)


def test_build_dataset_script(tmp_path):
    import json

    _make_tree(tmp_path, n=1)
    script = Path(__file__).resolve().parents[1] / "scripts" / "build_dataset.py"
    out = tmp_path / "results/datasets/clean_buffers/pairs.jsonl"
    subprocess.run([sys.executable, str(script), "--variant", "clean_buffers", "--out-root", "results",
                    "--plans-json", json.dumps(PLANS), "--output", str(out)], cwd=tmp_path, check=True)
    assert len(out.read_text().splitlines()) == 4
