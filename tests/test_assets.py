"""Asset generation and curation: rejection reasons, decimation, normalisation, determinism."""

import json
from pathlib import Path

import numpy as np
import pytest

from lightcrafter import assets


@pytest.fixture(scope="module")
def curated(tmp_path_factory):
    d = tmp_path_factory.mktemp("assets")
    assets.write_procedural_assets(d / "raw", seed=3, count=4, heavy_every=4, include_faulty=True)
    (d / "raw" / "empty.glb").write_bytes(b"")
    settings = assets.CurationSettings(target_size_m=0.8, max_faces=5000)
    manifest = assets.curate_folder(d / "raw", d / "cur", d / "manifest.json", settings, logger=lambda m: None)
    return d, manifest


def test_rejections_carry_reasons(curated):
    _, m = curated
    reasons = {r["id"]: r["reason"] for r in m["rejected"]}
    assert set(reasons) == {"faulty_truncated", "faulty_flat", "empty"}
    assert reasons["faulty_truncated"].startswith("unreadable")
    assert reasons["empty"].startswith("unreadable: empty file")
    assert reasons["faulty_flat"].startswith("degenerate: flat")


def test_heavy_mesh_is_decimated_not_dropped(curated):
    _, m = curated
    heavy = [a for a in m["accepted"] if a["id"] == "proc_0003"][0]
    assert heavy["faces_in"] > 100_000
    assert heavy["decimated"] and heavy["faces_out"] <= 5000


def test_curated_assets_are_normalised_y_up(curated):
    import trimesh

    _, m = curated
    assert len(m["accepted"]) == 4
    for a in m["accepted"]:
        scene = trimesh.load(a["path"], force="scene")
        lo, hi = scene.bounds
        assert np.isclose((hi - lo).max(), 0.8, atol=1e-4), a["id"]  # largest extent = target size
        assert abs(lo[1]) < 1e-4  # base on the ground (glTF y = 0)
        assert abs(lo[0] + hi[0]) < 1e-4 and abs(lo[2] + hi[2]) < 1e-4  # centred in x and z
        assert np.isclose(hi[1], a["height_m"], atol=1e-4)
        # Materials survive: PBR with a base-colour texture.
        geom = next(iter(scene.geometry.values()))
        assert geom.visual.material.baseColorTexture is not None


def test_generation_is_deterministic(tmp_path):
    a = assets.write_procedural_assets(tmp_path / "a", seed=5, count=3)
    b = assets.write_procedural_assets(tmp_path / "b", seed=5, count=3)
    c = assets.write_procedural_assets(tmp_path / "c", seed=6, count=3)
    assert [p.read_bytes() for p in a] == [p.read_bytes() for p in b]
    assert [p.read_bytes() for p in a] != [p.read_bytes() for p in c]


def test_generated_assets_come_at_arbitrary_scale(tmp_path):
    import trimesh

    paths = assets.write_procedural_assets(tmp_path, seed=0, count=8)
    sizes = [np.ptp(trimesh.load(p, force="scene").bounds, axis=0).max() for p in paths]
    assert max(sizes) / min(sizes) > 10  # like Objaverse: no common unit or scale


def test_missing_folder_is_a_one_line_error(tmp_path):
    from lightcrafter.io import DataError

    with pytest.raises(DataError, match="asset folder not found"):
        assets.curate_folder(tmp_path / "nope", tmp_path / "o", tmp_path / "m.json", assets.CurationSettings())


def test_objaverse_layout_is_read_at_any_depth_and_an_empty_tree_is_one_line(tmp_path):
    """Objaverse stores glbs/000-xxx/<uid>.glb: nested assets are curated; a tree without any GLB, or two
    assets of one name, is a one-line error naming the folder."""
    from lightcrafter.io import DataError

    src = tmp_path / "glbs"
    flat = assets.write_procedural_assets(tmp_path / "gen", seed=0, count=3)
    for i, p in enumerate(flat):
        (src / f"000-{i:03d}").mkdir(parents=True)
        (src / f"000-{i:03d}" / f"uid{i}.glb").write_bytes(Path(p).read_bytes())
    m = assets.curate_folder(src, tmp_path / "cur", tmp_path / "m.json", assets.CurationSettings(), logger=lambda m: None)
    assert sorted(a["id"] for a in m["accepted"] + m["rejected"]) == ["uid0", "uid1", "uid2"]
    (tmp_path / "empty" / "000-000").mkdir(parents=True)
    with pytest.raises(DataError, match="no .glb file at any depth"):
        assets.curate_folder(tmp_path / "empty", tmp_path / "o", tmp_path / "m2.json", assets.CurationSettings())
    (src / "000-009").mkdir()
    (src / "000-009" / "uid0.glb").write_bytes(Path(flat[0]).read_bytes())
    with pytest.raises(DataError, match="two assets are named 'uid0'"):
        assets.curate_folder(src, tmp_path / "o", tmp_path / "m3.json", assets.CurationSettings())


def test_manifest_is_deterministic(curated, tmp_path):
    d, m = curated
    again = assets.curate_folder(d / "raw", tmp_path / "cur", tmp_path / "m.json",
                                 assets.CurationSettings(target_size_m=0.8, max_faces=5000), logger=lambda m: None)
    strip = lambda man: [{k: v for k, v in a.items() if k not in ("path",)} for a in man["accepted"]]
    assert strip(again) == strip(json.loads((d / "manifest.json").read_text()))


def test_sharded_curation_merges_to_the_one_job_manifest_and_resumes_per_asset(curated, tmp_path):
    """Curation as an array of 3 jobs gives the one-job manifest; a rerun after a job was killed
    mid-way redoes only the asset it had not finished, and a changed setting redoes all."""
    d, whole = curated
    settings = assets.CurationSettings(target_size_m=0.8, max_faces=5000)
    out = d / "cur"                                     # the one-job run's folder: its records are reused
    shards = [tmp_path / f"{k}.json" for k in range(3)]
    done = []
    for k, path in enumerate(shards):
        assets.curate_folder(d / "raw", out, path, settings, logger=done.append, shard=(k, 3))
    assert done == []                                   # every asset reused from the one-job run
    merged = assets.merge_manifests(shards, tmp_path / "manifest.json")
    assert merged == whole and (tmp_path / "manifest.json").read_bytes() == (d / "manifest.json").read_bytes()
    # a job killed after writing one GLB and before its record: that asset alone is redone
    victim = merged["accepted"][0]
    (out / f"{victim['id']}.record.json").unlink()
    k = next(i for i, s in enumerate(shards) if victim["id"] in {e["id"] for e in json.loads(s.read_text())["accepted"]})
    assets.curate_folder(d / "raw", out, shards[k], settings, logger=done.append, shard=(k, 3))
    assert len(done) == 1 and victim["id"] in done[0]
    # a curated GLB changed on disk is not trusted
    Path(victim["path"]).write_bytes(b"garbage")
    done.clear()
    assets.curate_folder(d / "raw", out, shards[k], settings, logger=done.append, shard=(k, 3))
    assert len(done) == 1 and Path(victim["path"]).read_bytes()[:4] == b"glTF"
    # other settings: nothing reused
    done.clear()
    assets.curate_folder(d / "raw", out, tmp_path / "other.json", assets.CurationSettings(target_size_m=0.5, max_faces=5000),
                         logger=done.append)
    assert len(done) == len(whole["accepted"]) + len(whole["rejected"])
