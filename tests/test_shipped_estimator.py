"""The shipped G-buffer estimator (recon.estimator.weights: shipped): it loads, it reproduces the errors its
provenance file records on the shipped check frames, the provenance names how it was made, and bad
weights files get one line naming the file and the fix."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
import torch

from lightcrafter import io
from lightcrafter.recon import estimator as est
from lightcrafter.recon.weights import SHIPPED_PROVENANCE, SHIPPED_WEIGHTS, check_set_path, member_records, weights_path

REPO = Path(__file__).resolve().parents[1]


def test_shipped_weights_reproduce_their_recorded_validation_errors():
    prov = io.read_json(SHIPPED_PROVENANCE)
    assert hashlib.sha256(SHIPPED_WEIGHTS.read_bytes()).hexdigest() == prov["sha256"]
    errors = est.check_set_errors(est.load(SHIPPED_WEIGHTS), check_set_path())
    for k, v in prov["check_set_errors"].items():
        assert errors[k] == pytest.approx(v, rel=1e-3, abs=1e-4), k
    # and they are errors worth shipping: the goals of Phi's default (albedo >= 20 dB, normals <= 10 deg)
    # are checked on the run's test clips (results/summary/reconstruction.json); here, on held-out frames,
    # the weights must be far better than an untrained network
    torch.manual_seed(0)
    widths = member_records(prov)[0]["estimator"]["widths"]
    untrained = est.check_set_errors(est.GBufferNet(widths).eval(), check_set_path())
    assert errors["normal_deg"] < 0.5 * untrained["normal_deg"]
    assert errors["albedo_psnr_db"] > untrained["albedo_psnr_db"] + 3


def test_provenance_names_the_commit_config_data_and_curve_of_every_member():
    prov = io.read_json(SHIPPED_PROVENANCE)
    shipped = est.load(SHIPPED_WEIGHTS)
    records = member_records(prov)
    members = shipped.members if isinstance(shipped, est.EstimatorEnsemble) else [shipped]
    assert len(records) == len(members)
    for rec, net in zip(records, members):
        assert len(rec["commit"]) == 40 and rec["config_file"].startswith("estimator")
        assert (REPO / "config" / rec["config_file"]).is_file()
        assert rec["data"]["train_frames"] > 0 and rec["data"]["scenes"] > 1
        steps = [p["setting"] for p in rec["curve"] if p["series"] == "normal_deg"]
        secs = [p["seconds"] for p in rec["curve"] if p["series"] == "normal_deg"]
        assert steps == sorted(steps) and secs == sorted(secs) and rec["selected_step"] in steps
        assert rec["parameters"] == sum(p.numel() for p in net.parameters())
        # each member alone reproduces its own recorded errors on the check set
        errors = est.check_set_errors(net.eval(), check_set_path())
        for k, v in rec["check_set_errors"].items():
            assert errors[k] == pytest.approx(v, rel=1e-3, abs=1e-4), k
    assert prov["parameters"] == sum(p.numel() for p in shipped.parameters())
    if len(records) > 1:  # members differ in their seed or training settings (no two alike), not in schedule
        settings = [repr(sorted(r["estimator"].items())) for r in records]
        assert len(set(settings)) == len(settings)
        assert {r["estimator"]["steps"] for r in records} == {records[0]["estimator"]["steps"]}


def _member_file(path, seed: int, widths=(8, 16)) -> dict:
    torch.manual_seed(seed)
    net = est.GBufferNet(list(widths), "direct_colour")
    cfg = est.EstimatorConfig.from_dict({"widths": list(widths), "albedo_head": "direct_colour", "seed": seed})
    est.save(net, cfg, path)
    return torch.load(path, map_location="cpu", weights_only=False)


def test_an_ensemble_file_averages_its_members_predictions(tmp_path):
    """lightcrafter.recon.estimator.EstimatorEnsemble through save_ensemble/load: depth is the members' geometric
    mean, albedo, roughness, metallic their mean, normals the renormalised mean (unit length); two copies of one
    network predict what it predicts."""
    a, b = _member_file(tmp_path / "a.pt", 0), _member_file(tmp_path / "b.pt", 1)
    est.save_ensemble([a, b], tmp_path / "ab.pt")
    est.save_ensemble([a, a], tmp_path / "aa.pt")
    ens = est.load(tmp_path / "ab.pt")
    assert isinstance(ens, est.EstimatorEnsemble) and len(ens.members) == 2
    frame = np.random.default_rng(0).random((16, 24, 3)).astype(np.float32)
    pa, pb = est.predict(est.load(tmp_path / "a.pt"), frame), est.predict(est.load(tmp_path / "b.pt"), frame)
    pab, paa = est.predict(ens, frame), est.predict(est.load(tmp_path / "aa.pt"), frame)
    assert np.allclose(pab["depth"], np.sqrt(pa["depth"] * pb["depth"]), rtol=1e-4)
    for k in ("albedo", "roughness", "metallic"):
        assert np.allclose(pab[k], (pa[k] + pb[k]) / 2, atol=1e-6), k
    assert np.allclose(np.linalg.norm(pab["normal_cam"], axis=-1), 1.0, atol=1e-5)
    mean_n = pa["normal_cam"] + pb["normal_cam"]
    assert np.allclose(pab["normal_cam"], mean_n / np.linalg.norm(mean_n, axis=-1, keepdims=True), atol=1e-5)
    for k in pa:
        assert np.allclose(paa[k], pa[k], atol=1e-5), k


@pytest.mark.parametrize("case", ["no_members", "member_of_another_shape", "member_not_a_network"])
def test_bad_ensemble_files_get_one_line_naming_the_file_and_the_member(tmp_path, case):
    a = _member_file(tmp_path / "a.pt", 0)
    p = tmp_path / "ens.pt"
    if case == "no_members":
        torch.save({"format": est.ENSEMBLE_FORMAT, "members": []}, p)
    elif case == "member_of_another_shape":
        est.save_ensemble([a, {**a, "config": {**a["config"], "widths": [4, 8, 16]}}], p)
    else:
        est.save_ensemble([a, {"weights": np.zeros(3)}], p)
    with pytest.raises(io.DataError) as exc:
        est.load(p)
    msg = str(exc.value)
    assert str(p) in msg and "\n" not in msg and "recon.estimator.weights" in msg
    if case != "no_members":
        assert "(member 1)" in msg


def test_weights_key_resolves_train_shipped_and_paths(tmp_path):
    assert weights_path("train", tmp_path / "m.pt") == tmp_path / "m.pt"
    assert weights_path("shipped", tmp_path / "m.pt") == SHIPPED_WEIGHTS
    assert weights_path(str(tmp_path / "x.pt"), "unused") == tmp_path / "x.pt"


@pytest.mark.parametrize("case", ["missing", "garbage", "truncated", "other_shape", "foreign_pickle"])
def test_bad_weights_files_get_one_line_naming_the_file_and_the_fix(tmp_path, case):
    p = tmp_path / "weights.pt"
    if case == "garbage":
        p.write_bytes(b"\x00not a torch file" * 50)
    elif case == "truncated":
        p.write_bytes(SHIPPED_WEIGHTS.read_bytes()[:2000])
    elif case == "other_shape":
        st = torch.load(SHIPPED_WEIGHTS, map_location="cpu", weights_only=False)
        st = st["members"][0] if "members" in st else st  # one network of the shipped ensemble
        st["config"]["widths"] = [8, 16]
        torch.save(st, p)
    elif case == "foreign_pickle":
        torch.save({"weights": np.zeros(3)}, p)
    with pytest.raises(io.DataError) as exc:
        est.load(p)
    msg = str(exc.value)
    assert str(p) in msg and "\n" not in msg and "recon.estimator.weights" in msg


def test_a_weights_key_naming_a_missing_file_stops_the_run_at_start_up(tmp_path):
    from lightcrafter.config import effective_config
    from lightcrafter.scenes import ConfigError

    missing = tmp_path / "nowhere.pt"
    with pytest.raises(ConfigError) as exc:
        effective_config(overrides={"recon": {"estimator": {"weights": str(missing)}}})
    assert "recon.estimator.weights" in str(exc.value) and str(missing) in str(exc.value)
    assert "\n" not in str(exc.value)


def test_estimator_validation_holds_out_a_trajectory_under_all_its_lights():
    """scripts/train_estimator.py: with fewer than 8 scenes the last trajectory validates, under every light it
    was rendered under (scenes.recon_lightings): none of its videos trains; with 8 scenes, the last one's."""
    import importlib.util
    import sys

    sys.path.insert(0, str(REPO / "scripts"))
    spec = importlib.util.spec_from_file_location("train_estimator_script", REPO / "scripts" / "train_estimator.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)

    def pairs(scenes, lights):
        return sorted((f"gt/s{s:04d}/t{t}/buffers.json", f"gt/s{s:04d}/t{t}/rgb/L{k}.json")
                      for s in range(scenes) for t in range(3) for k in lights)

    val, train = mod.validation_split(pairs(2, (0, 2, 3)))
    assert [c for c, _ in val] == ["gt/s0001/t2/buffers.json"] * 3 and len(train) == 15
    assert not {c for c, _ in val} & {c for c, _ in train}
    val, train = mod.validation_split(pairs(8, (1,)))
    assert {c.split("/")[1] for c, _ in val} == {"s0007"} and len(val) == 3 and len(train) == 21
    one = pairs(1, (0, 1))[:2]
    assert mod.validation_split(one) == (one, one)


def test_estimator_ensemble_script_writes_the_named_members_and_nothing_for_a_bad_name(tmp_path, monkeypatch):
    """scripts/estimator_ensemble.py: shipped:N picks the shipped file's member N, a network file adds itself, an
    ensemble file adds each of its members, in the order named; a shipped index out of range or not a number, a
    missing file and a file with a member that does not fit its network are one line each, and no file is written."""
    import importlib.util

    monkeypatch.syspath_prepend(str(REPO / "scripts"))
    spec = importlib.util.spec_from_file_location("estimator_ensemble", REPO / "scripts" / "estimator_ensemble.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    a, b = _member_file(tmp_path / "a.pt", 0), _member_file(tmp_path / "b.pt", 1)
    est.save_ensemble([b, a], tmp_path / "ba.pt")
    shipped = torch.load(SHIPPED_WEIGHTS, map_location="cpu", weights_only=False)["members"]
    out = tmp_path / "mine.pt"
    assert script.main(["--out", str(out), "shipped:2", str(tmp_path / "a.pt"), str(tmp_path / "ba.pt")]) == 0
    members = torch.load(out, map_location="cpu", weights_only=False)["members"]
    assert [len(m["state"]) for m in members] == [len(shipped[2]["state"])] + [len(a["state"])] * 3
    for got, want in zip(members, [shipped[2], a, b, a]):
        assert all(torch.equal(got["state"][k], want["state"][k]) for k in want["state"])
    assert len(est.load(out).members) == 4
    assert script.main(["--out", str(tmp_path / "all.pt"), "shipped"]) == 0
    assert len(est.load(tmp_path / "all.pt").members) == len(shipped)
    broken = {**a, "state": dict(list(a["state"].items())[1:])}  # a member whose weights miss a tensor
    est.save_ensemble([a, broken], tmp_path / "broken.pt")
    for bad, says in ((f"shipped:{len(shipped)}", f"has {len(shipped)} member(s)"), ("shipped:x", "shipped:N"),
                      (str(tmp_path / "none.pt"), "not found"), (str(tmp_path / "broken.pt"), "(member 1) do not fit")):
        with pytest.raises(io.DataError) as exc:
            script.main(["--out", str(tmp_path / "bad.pt"), "shipped:0", bad])
        assert says in str(exc.value) and "\n" not in str(exc.value)
        assert not (tmp_path / "bad.pt").exists()
