"""The paper preset's code paths on the CPU: device policy, fp32 master weights, the real checkpoint
format (a tiny CogVideoX-I2V folder written on the spot), its bad-input errors, and the rehearsal."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from lightcrafter.refiner import resolve_config

REPO = Path(__file__).resolve().parents[1]
SCRIPTS = REPO / "scripts"


@pytest.fixture(scope="module")
def tiny_ckpt(tmp_path_factory):
    from lightcrafter.refiner.standin import write_tiny_checkpoint

    return write_tiny_checkpoint(tmp_path_factory.mktemp("ckpt") / "CogVideoX-tiny-I2V")


# ----------------------------------------------------------------------------- devices
def test_cuda_device_without_a_gpu_is_one_line_naming_the_key(monkeypatch):
    from lightcrafter.devices import NoGPUError, resolve_device

    if torch.cuda.is_available():
        pytest.skip("a GPU is present")
    with pytest.raises(NoGPUError, match=r"refiner.device=cuda: .*sees no CUDA GPU.*set refiner.device: cpu"):
        resolve_device("cuda", "refiner.device")
    assert resolve_device("auto").type == "cpu"
    monkeypatch.setenv("SLURM_GPUS_ON_NODE", "1")  # the profile gave the job a GPU torch cannot see
    with pytest.raises(NoGPUError, match="given a GPU .SLURM_GPUS_ON_NODE=1"):
        resolve_device("auto", "refiner.device")
    assert resolve_device("cpu").type == "cpu"  # the tiny preset keeps running on the CPU


def test_the_estimator_follows_the_same_policy():
    from lightcrafter.devices import NoGPUError
    from lightcrafter.recon.estimator import EstimatorConfig, GBufferNet, Sample, predict, train_estimator

    if torch.cuda.is_available():
        pytest.skip("a GPU is present")
    assert EstimatorConfig.from_dict({}).device == "cpu"
    s = Sample(*(torch.zeros(n, 16, 16) for n in (3, 1, 3, 3, 1, 1, 1)))
    s.log_depth, s.roughness, s.metallic, s.mask = (torch.zeros(16, 16) for _ in range(4))
    with pytest.raises(NoGPUError, match="recon.estimator.device=cuda"):
        train_estimator([s], [], EstimatorConfig.from_dict({"device": "cuda", "steps": 1}), log=lambda m: None)
    assert predict(GBufferNet([4, 8]), np.zeros((16, 16, 3), np.float32))["depth"].shape == (16, 16)


def test_presets_pick_their_devices():
    assert resolve_config({"preset": "tiny"})["device"] == "cpu"
    assert resolve_config({"preset": "paper"})["device"] == "cuda"


def test_training_script_with_the_paper_preset_and_no_gpu_fails_at_once(tmp_path):
    if torch.cuda.is_available():
        pytest.skip("a GPU is present")
    (tmp_path / "pairs.jsonl").write_text("")
    cfg = {"preset": "paper", "model": {"model_path": str(tmp_path / "nowhere")}}
    r = subprocess.run([sys.executable, SCRIPTS / "train_refiner.py", "--pairs", tmp_path / "pairs.jsonl",
                        "--config-json", json.dumps(cfg), "--out", tmp_path / "m"], capture_output=True, text=True)
    assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "refiner.device=cuda" in r.stderr and "no CUDA GPU" in r.stderr


# ----------------------------------------------------------------------------- precision
def _changed_fraction(before: dict, after: dict) -> float:
    n = sum(v.numel() for v in before.values())
    return sum(int((after[k].float() != v.float()).sum()) for k, v in before.items()) / n


def test_one_adamw_step_at_lr_1e5_changes_99_percent_of_a_bf16_models_weights(tmp_path):
    """fp32 master weights: the step is kept. Stepping the bf16 parameters directly (the old path)
    rounds most updates away -- the reason for the masters."""
    from lightcrafter.refiner import Refiner, train
    from lightcrafter.refiner.toy import ToyDataset
    from lightcrafter.refiner.training import training_loss
    from lightcrafter.refiner.schedule import build_scheduler

    cfg = resolve_config({"model": {"ae_coeffs": [8, 4, 4], "dtype": "bfloat16", "proxy_anchor": "none",
                                    "anchor_affine": False},
                          "train": {"max_steps": 1, "lr": 1e-5, "warmup_steps": 0, "grad_accum": 1,
                                    "timesteps": "all"}})
    torch.manual_seed(cfg["seed"])
    init = {k: v.clone() for k, v in Refiner(cfg, training=True).transformer.state_dict().items()}
    train(cfg, ToyDataset(2), tmp_path, progress=False)
    after = torch.load(tmp_path / "model.pt", weights_only=False)["transformer"]
    assert after["proj_out.weight"].dtype == torch.float32
    assert _changed_fraction(init, after) >= 0.99

    torch.manual_seed(cfg["seed"])
    naive = Refiner(cfg, training=False)  # parameters in bf16
    assert naive.param_dtype == torch.bfloat16
    before = {k: v.clone() for k, v in naive.transformer.state_dict().items()}
    opt = torch.optim.AdamW(naive.transformer.parameters(), lr=1e-5)
    item = ToyDataset(2)[0]
    naive.ae.fit_normalisation([item["target"][None]])
    zt, zp = naive.ae.encode(item["target"][None]), naive.ae.encode(item["proxy"][None])
    g = torch.Generator().manual_seed(0)
    training_loss(naive, build_scheduler(cfg, "ddim"), zt, zp, torch.tensor([500]),
                  torch.randn(zt.shape, generator=g)).backward()
    opt.step()
    assert _changed_fraction(before, naive.transformer.state_dict()) < 0.5


# ----------------------------------------------------------------------------- the real format
def test_tiny_checkpoint_has_the_released_layout_and_loads_through_from_pretrained(tiny_ckpt):
    from lightcrafter.refiner import Refiner
    from lightcrafter.refiner.checkpoint import read_servable

    for sub in ("transformer", "vae", "text_encoder", "tokenizer", "scheduler"):
        assert (tiny_ckpt / sub).is_dir()
    assert (tiny_ckpt / "tokenizer" / "spiece.model").is_file()
    assert not (tiny_ckpt / "tokenizer" / "tokenizer.json").exists()  # as released: converted on load
    s = read_servable(tiny_ckpt)
    assert (s.in_channels, s.latent_channels, s.width_px, s.height_px, s.window_latent) == (32, 16, 48, 32, 13)
    cfg = resolve_config({"preset": "paper", "device": "cpu", "model": {"model_path": str(tiny_ckpt)}})
    m = Refiner(cfg)
    assert m.fixed_window == 13 and m.fixed_latent_hw == (4, 6)
    assert m.prompt_embeds.shape == (1, 226, 32) and m.prompt_embeds.abs().sum() > 0  # T5 of ""
    z = torch.zeros(1, 12, 16, 4, 6)
    with pytest.raises(ValueError, match=r"learned positional embeddings serve 13x4x6 only"):
        m(z, z, torch.tensor([10]))  # diffusers would silently swap in sin-cos embeddings


def test_a_vae_that_cannot_reconstruct_stops_paper_training_in_one_line_naming_its_folder(tiny_ckpt, tmp_path):
    """The stand-in's VAE has random weights, as a wrong or mismatched VAE would: its round trip (about 15 dB) is
    below refiner.model.min_ae_round_trip_db, checked before the first step with the paper preset's VAE."""
    from lightcrafter.io import DataError
    from lightcrafter.refiner import train
    from lightcrafter.refiner.toy import ToyDataset

    cfg = resolve_config({"preset": "paper", "device": "cpu", "model": {"model_path": str(tiny_ckpt)},
                          "train": {"max_steps": 1}})
    with pytest.raises(DataError) as exc:
        train(cfg, ToyDataset(1), tmp_path, progress=False)
    msg = str(exc.value)
    assert msg.startswith(f"{tiny_ckpt}/vae: the autoencoder's round trip is 1") and "\n" not in msg
    assert "min_ae_round_trip_db = 25" in msg and not list((tmp_path / "checkpoints").glob("*"))


def _broken(tiny_ckpt, tmp_path, edit):
    root = tmp_path / "broken"
    shutil.copytree(tiny_ckpt, root)
    edit(root)
    return root


def _startup_error(root, **over):
    from lightcrafter.config import ConfigError, check_startup, validate

    cfg = validate({"assets": {"source": "procedural"}, "recon": {"backend": "default"},
                    "refiner": {"preset": "paper", "model": {"model_path": str(root)}},
                    "scenes": {"width": over.get("width", 48), "height": 32}}, "site.yaml")
    with pytest.raises(ConfigError) as e:
        check_startup(cfg, "site.yaml")
    assert "\n" not in str(e.value)
    return str(e.value)


def test_bad_model_folders_are_one_line_at_config_time(tiny_ckpt, tmp_path):
    def drop_vae(r):
        shutil.rmtree(r / "vae")

    assert "lacks vae/" in _startup_error(_broken(tiny_ckpt, tmp_path / "a", drop_vae))

    def t2v(r):
        c = json.loads((r / "transformer" / "config.json").read_text())
        (r / "transformer" / "config.json").write_text(json.dumps({**c, "in_channels": 16}))

    msg = _startup_error(_broken(tiny_ckpt, tmp_path / "b", t2v))
    assert "in_channels=16" in msg and "transformer/config.json" in msg and "I2V" in msg

    def no_tokenizer(r):
        (r / "tokenizer" / "spiece.model").unlink()

    assert "neither spiece.model nor tokenizer.json" in _startup_error(_broken(tiny_ckpt, tmp_path / "c", no_tokenizer))
    # the learned embeddings serve 48x32 and 13 latent frames only
    msg = _startup_error(tiny_ckpt, width=64)
    assert "serve 48x32 pixels only" in msg and "scenes.width: 48" in msg


def test_a_tokenizer_that_cannot_load_is_one_line_naming_it(tiny_ckpt, tmp_path):
    from lightcrafter.refiner import Refiner
    from lightcrafter.refiner.checkpoint import CheckpointError

    root = _broken(tiny_ckpt, tmp_path, lambda r: (r / "tokenizer" / "spiece.model").write_bytes(b"not a model"))
    cfg = resolve_config({"preset": "paper", "device": "cpu", "model": {"model_path": str(root)}})
    with pytest.raises(CheckpointError, match=r"tokenizer: the T5 tokenizer does not load"):
        Refiner(cfg)


@pytest.mark.slow
def test_rehearsal_trains_resumes_refines_and_relights_with_the_paper_preset(e2e_run, tmp_path):
    """scripts/rehearse_refiner.py (the GPU check runs it with --device cuda); the relight step uses the
    default run's G-buffer estimator."""
    r = subprocess.run([sys.executable, SCRIPTS / "rehearse_refiner.py", "--out", tmp_path, "--steps", "4",
                        "--estimator", e2e_run / "results/recon/estimator/model.pt"],
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    rep = json.loads((tmp_path / "rehearsal.json").read_text())
    tr = rep["train"]
    assert tr["steps"] == 4 and tr["steps_before_kill"] == 2 and tr["resumed"]
    assert tr["param_dtype"] == "torch.float32" and tr["fraction_of_weights_changed"] >= 0.99
    inf = rep["infer"]
    assert inf["pairs"] == {"t0": 61, "t1": 9}  # two fused windows; a short clip repeated to the window
    assert (inf["sampler"], inf["guidance_scale"], inf["window"], inf["overlap"]) == ("dpm", 6.0, 13, 3)
    assert inf["second_run_resumed"] == 2  # the rerun refined nothing
    from lightcrafter.io import read_rgb_exr

    rl = rep["relight"]
    assert rl["num_frames"] == 13 and Path(rl["strip"]).is_file() and Path(rl["video"]).is_file()
    assert (rl["infer"]["sampler"], rl["infer"]["window"], rl["infer"]["pad_frames"]) == ("dpm", 13, "repeat_last")
    frames = sorted((tmp_path / "refined" / "t0").glob("*.exr"))
    assert len(frames) == 61 and all(torch.isfinite(torch.from_numpy(read_rgb_exr(f))).all() for f in frames[::10])


# ----------------------------------------------------------------------------- several processes
def test_data_parallel_training_on_two_processes_writes_once_and_keeps_each_ranks_state(tmp_path):
    """torchrun with 2 CPU processes (gloo): the code path of accelerate launch on 2 GPUs."""
    from lightcrafter.io import display_to_linear, write_jsonl, write_rgb_exr
    from lightcrafter.refiner.toy import toy_pair

    recs = []
    for i in range(3):
        p = toy_pair(i, num_frames=5)
        for key in ("proxy", "target"):
            disp = ((p[key].numpy().transpose(1, 2, 3, 0) + 1) / 2).clip(0, 1)
            for f, frame in enumerate(disp):
                write_rgb_exr(tmp_path / f"p{i}" / key / f"{f:04d}.exr", display_to_linear(frame))
        recs.append({"pair_id": f"p{i}", "kind": "synthetic", "scene_id": f"s{i}", "proxy": f"p{i}/proxy",
                     "target": f"p{i}/target", "num_frames": 5, "width": 48, "height": 32, "split": "train"})
    write_jsonl(tmp_path / "pairs.jsonl", recs)
    cfg = {"model": {"ae_coeffs": [8, 4, 4]}, "select": {"val_scenes": 0},
           "baselines": {"regressor_steps": 0, "affine_colour": False},
           "train": {"max_steps": 2, "checkpoint_every": 1, "grad_accum": 1, "num_workers": 1}}

    def launch(steps):
        cmd = [sys.executable, "-m", "torch.distributed.run", "--nproc_per_node", "2", SCRIPTS / "train_refiner.py",
               "--pairs", "pairs.jsonl", "--config-json",
               json.dumps({**cfg, "train": {**cfg["train"], "max_steps": steps}}), "--out", "m"]
        r = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, r.stderr[-3000:]
        return r

    launch(2)
    ck = tmp_path / "m" / "checkpoints"
    assert (ck / "step_0000002.pt").is_file() and (ck / "step_0000002.rank1.pt").is_file()
    g0 = torch.load(ck / "step_0000002.pt", weights_only=False)["generator"]
    g1 = torch.load(ck / "step_0000002.rank1.pt", weights_only=False)["generator"]
    assert not torch.equal(g0, g1)  # per-rank seeds: the ranks draw different samples
    launch(3)  # a longer run resumes both ranks from step 2
    assert "resumed from step_0000002.pt at step 2" in (tmp_path / "m" / "train.log").read_text()
    assert len(json.loads((tmp_path / "m" / "loss_curve.json").read_text())["loss_per_optimizer_step"]) == 3
    assert torch.load(tmp_path / "m" / "model.pt", weights_only=False)["train"]["steps"] == 3


def test_the_train_rule_launches_one_process_per_configured_gpu(tmp_path):
    from workflow_util import venv_env

    cmd = [sys.executable, "-m", "snakemake", "-n", "-p", "--cores", "1", "-d", str(tmp_path), "--configfile",
           str(REPO / "config" / "ci.yaml"), "--config", "refiner={resources: {gpus: 2}}", "--",
           "results/refiner/full/model.pt"]
    r = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=300, env=venv_env())
    assert r.returncode == 0, r.stderr[-2000:]
    assert "accelerate launch --multi_gpu --num_machines 1 --num_processes 2" in r.stdout


def test_the_full_size_stand_in_has_cogvideox_5b_i2v_s_transformer():
    """benchmarks/refiner_step.py measures memory on this stand-in: its transformer must be the released
    one's shape (built on the meta device here: no memory), with 5B-I2V's config fields."""
    from diffusers import CogVideoXTransformer3DModel

    from lightcrafter.refiner.standin import COGVIDEOX_5B_I2V_TRANSFORMER, transformer_kwargs

    kw = transformer_kwargs(height_px=480, width_px=720, frames=49, full_size=True)
    with torch.device("meta"):
        net = CogVideoXTransformer3DModel(**kw)
    for key, want in COGVIDEOX_5B_I2V_TRANSFORMER.items():
        assert net.config[key] == want, key
    n = sum(p.numel() for p in net.parameters())
    assert 5.4e9 < n < 5.8e9  # "5B": 42 blocks of width 48 x 64 = 3072
    tiny = sum(p.numel() for p in CogVideoXTransformer3DModel(
        **transformer_kwargs(height_px=32, width_px=48, frames=49)).parameters())
    assert tiny < 1e5


def test_training_step_benchmark_runs_the_paper_preset_and_reports_each_step(tmp_path):
    """benchmarks/refiner_step.py --size tiny on the CPU: the path the GPU check takes at full size (paper
    preset through train(), checkpoint writes skipped): one time per optimizer step, finite losses, and
    no checkpoint file left behind."""
    root = Path(__file__).resolve().parents[1]
    out = tmp_path / "step.json"
    r = subprocess.run([sys.executable, str(root / "benchmarks" / "refiner_step.py"), "--size", "tiny", "--device", "cpu",
                        "--steps", "2", "--work", str(tmp_path / "w"), "--out", str(out)],
                       capture_output=True, text=True, cwd=root, timeout=900)
    assert r.returncode == 0, r.stderr[-2000:]
    res = json.loads(out.read_text())
    assert len(res["step_seconds"]) == 2 and all(s > 0 for s in res["step_seconds"])
    assert res["seconds_per_step_after_first"]["n"] == 1
    assert len(res["losses"]) == 2 and all(np.isfinite(res["losses"]))
    assert res["preset"]["dtype"] == "bfloat16" and res["preset"]["gradient_checkpointing"]
    assert 1e4 < res["transformer_parameters"] < 1e5
    assert not list((tmp_path / "w" / "refiner").rglob("*.pt"))
    r = subprocess.run([sys.executable, str(root / "benchmarks" / "refiner_step.py"), "--size", "tiny", "--device", "cpu",
                        "--steps", "1", "--out", str(tmp_path / "x.json")], capture_output=True, text=True, cwd=root,
                       timeout=300)
    assert r.returncode != 0 and "--steps 1" in r.stderr.splitlines()[-1]
