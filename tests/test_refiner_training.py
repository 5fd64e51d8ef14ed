"""Training: finite decreasing-ish loss, bit-for-bit resume, exact target-latent cache."""

import json

import pytest
import torch

from lightcrafter.refiner import load_model, resolve_config, train
from lightcrafter.refiner.toy import ToyDataset
from lightcrafter.refiner.training import TargetLatentCache

torch.set_num_threads(1)

CFG = {"model": {"ae_coeffs": [8, 4, 4]}, "train": {"max_steps": 6, "checkpoint_every": 100, "lr": 1e-3}}


def test_resume_is_bit_for_bit(tmp_path):
    cfg = resolve_config(CFG)
    straight = train(cfg, ToyDataset(3), tmp_path / "a", progress=False)["losses"]
    first = train(cfg, ToyDataset(3), tmp_path / "b", progress=False, stop_after=3)
    assert first["step"] == 3 and not (tmp_path / "b" / "model.pt").exists()  # "killed" before the end
    resumed = train(cfg, ToyDataset(3), tmp_path / "b", progress=False)["losses"]
    assert len(straight) == 6 and resumed == straight
    a = torch.load(tmp_path / "a" / "model.pt", weights_only=False)["transformer"]
    b = torch.load(tmp_path / "b" / "model.pt", weights_only=False)["transformer"]
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert "resumed from" in (tmp_path / "b" / "train.log").read_text()
    curve = json.loads((tmp_path / "a" / "loss_curve.json").read_text())
    assert curve["loss_per_optimizer_step"] == straight
    # seconds per step over the whole training: a killed-and-resumed run counts both calls' steps, and a call on a
    # finished run (nothing left to train) keeps the figure instead of recording the ~0 s of loading a checkpoint
    timed = json.loads((tmp_path / "b" / "loss_curve.json").read_text())["seconds_per_optimizer_step"]
    assert timed > 1e-3 and timed == pytest.approx(curve["seconds_per_optimizer_step"], rel=2.0)
    again = train(cfg, ToyDataset(3), tmp_path / "b", progress=False)
    assert again["losses"] == straight and again["seconds_per_step"] == pytest.approx(timed, rel=0.5)
    assert json.loads((tmp_path / "b" / "loss_curve.json").read_text())["seconds_per_optimizer_step"] == \
        pytest.approx(timed, rel=0.5)


def test_resume_with_data_loading_workers_is_bit_for_bit(tmp_path):
    """train.num_workers > 0 (the paper preset): pairs are read in worker processes, ahead of the step."""
    cfg = resolve_config({**CFG, "train": {**CFG["train"], "num_workers": 2}})
    straight = train(cfg, ToyDataset(3), tmp_path / "a", progress=False)["losses"]
    train(cfg, ToyDataset(3), tmp_path / "b", progress=False, stop_after=3)
    resumed = train(cfg, ToyDataset(3), tmp_path / "b", progress=False)["losses"]
    assert len(straight) == 6 and resumed == straight
    inline = train(resolve_config(CFG), ToyDataset(3), tmp_path / "c", progress=False)["losses"]
    assert inline != straight  # another index stream: the workers really supplied the pairs


def test_checkpoint_of_another_config_is_not_resumed(tmp_path):
    """A config change (here: a wider latent) after a killed run trains afresh instead of crashing."""
    train(resolve_config(CFG), ToyDataset(3), tmp_path, progress=False, stop_after=2)
    other = resolve_config({**CFG, "model": {"ae_coeffs": [16, 8, 8]}})
    fresh = train(other, ToyDataset(3), tmp_path / "ref", progress=False)["losses"]
    again = train(other, ToyDataset(3), tmp_path, progress=False)["losses"]
    assert again == fresh
    assert "training from scratch" in (tmp_path / "train.log").read_text()


def test_trained_model_reloads_with_infer_overrides(tmp_path):
    cfg = resolve_config({**CFG, "train": {**CFG["train"], "max_steps": 1}})
    train(cfg, ToyDataset(1), tmp_path, progress=False)
    m = load_model(tmp_path / "model.pt", {"infer": {"num_steps": 3}})
    assert m.cfg["infer"]["num_steps"] == 3 and m.cfg["infer"]["window"] == cfg["infer"]["window"]


def test_a_checkpoint_of_another_architecture_or_a_broken_file_is_a_one_line_error(tmp_path):
    from lightcrafter.io import DataError

    cfg = resolve_config({**CFG, "train": {**CFG["train"], "max_steps": 1}})
    train(cfg, ToyDataset(1), tmp_path, progress=False)
    with pytest.raises(DataError, match=r"model.pt: weights of another architecture .*retrain it") as exc:
        load_model(tmp_path / "model.pt", {"model": {"ae_coeffs": [16, 8, 8]}})
    assert "\n" not in str(exc.value)
    (tmp_path / "broken.pt").write_bytes((tmp_path / "model.pt").read_bytes()[:200])
    with pytest.raises(DataError, match=r"broken.pt: not a refiner checkpoint"):
        load_model(tmp_path / "broken.pt")
    torch.save({"transformer": {}}, tmp_path / "other.pt")
    with pytest.raises(DataError, match=r"other.pt: not a refiner checkpoint \(no config"):
        load_model(tmp_path / "other.pt")


def test_an_autoencoder_that_cannot_reconstruct_its_targets_stops_training_in_one_line(tmp_path):
    """refiner.model.min_ae_round_trip_db: the refined clips are decoded by the autoencoder, so one whose round
    trip on the training targets is below the floor stops training before any step, naming its source."""
    from lightcrafter.io import DataError

    lossy = resolve_config({**CFG, "model": {"ae_coeffs": [1, 1, 1]}})  # one DCT coefficient per block: ~23 dB
    with pytest.raises(DataError) as exc:
        train(lossy, ToyDataset(2), tmp_path / "lossy", progress=False)
    msg = str(exc.value)
    assert "\n" not in msg and msg.startswith("refiner.model.ae_coeffs [1, 1, 1]: the autoencoder's round trip is 2")
    assert "below refiner.model.min_ae_round_trip_db = 25" in msg and "(toy0000, toy0001)" in msg
    assert not list((tmp_path / "lossy" / "checkpoints").glob("*")) and not (tmp_path / "lossy" / "model.pt").exists()
    # the floor lowered: the same autoencoder trains; the test's usual one passes and logs its figure
    train(resolve_config({**CFG, "model": {"ae_coeffs": [1, 1, 1], "min_ae_round_trip_db": 20.0},
                          "train": {**CFG["train"], "max_steps": 1}}), ToyDataset(2), tmp_path / "low", progress=False)
    train(resolve_config({**CFG, "train": {**CFG["train"], "max_steps": 1}}), ToyDataset(2), tmp_path / "ok",
          progress=False)
    logged = [ln for ln in (tmp_path / "ok" / "train.log").read_text().splitlines() if "round trip" in ln]
    assert len(logged) == 1 and 27.0 < float(logged[0].split(": ")[-1].split(" dB")[0]) < 32.0  # [8, 4, 4]: ~29 dB


def test_target_latent_cache_is_exact():
    from lightcrafter.refiner import DCTPatchAutoencoder

    ae = DCTPatchAutoencoder(16)
    cache = TargetLatentCache(ae)
    v = ToyDataset(1)[0]["target"]
    assert torch.equal(cache.get("p", v), ae.encode(v[None]))
    assert cache.get("p", v) is cache.get("p", v)


def test_checkpoint_past_max_steps_is_not_reused(tmp_path):
    """Lowering train.max_steps after a finished run retrains instead of shipping the longer run's weights."""
    train(resolve_config(CFG), ToyDataset(2), tmp_path, progress=False)
    short = resolve_config({**CFG, "train": {**CFG["train"], "max_steps": 3}})
    fresh = train(short, ToyDataset(2), tmp_path / "ref", progress=False)["losses"]
    again = train(short, ToyDataset(2), tmp_path, progress=False)
    assert again["step"] == 3 and again["losses"] == fresh
    assert "past train.max_steps" in (tmp_path / "train.log").read_text()
