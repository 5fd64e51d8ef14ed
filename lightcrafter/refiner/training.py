"""Refiner training loop: v-prediction loss, AdamW, gradient accumulation (accelerate),
bit-for-bit resumable checkpoints, tqdm progress bar and a plain-text log.

Randomness: every draw of a training step (pair index, latent crop, conditioning sigma and noise,
dropout coin, timestep, diffusion noise) comes from ONE ``torch.Generator`` seeded by ``cfg.seed``;
its state, the global torch/numpy/python RNG states, the model, the optimizer and the LR schedule
are saved in each checkpoint, at optimizer-step boundaries, so ``N straight`` and
``N/2 + resume + N/2`` give identical loss curves on the CPU. With ``train.num_workers`` > 0 the
pair index alone comes from a second seeded stream (:class:`PairIndexStream`) that a DataLoader's
worker processes read ahead; the checkpoint records how many pairs were consumed, and the resumed
stream skips exactly those, so resumption stays bit-for-bit.

Windows: each sample is a ``train.latent_window``-frame crop at a random offset of the globally
encoded clip, so (like tiled inference) most windows start with a 4-frame latent rather than the
causal 1-frame first latent.

Devices (``device``, lightcrafter/devices.py): the CPU for the tiny preset, CUDA for the paper
preset (an error, not a fallback, when there is none). All random draws stay on the CPU generator,
then move to the device.

Precision: with ``model.dtype: bfloat16`` the transformer keeps float32 master weights and computes
in bf16 under autocast (:class:`Refiner`, ``training=True``); the optimizer steps the fp32 weights.

Several GPUs (``accelerate launch --num_processes N``, the workflow does it for ``resources.gpus``
> 1): data parallel; rank r draws from its own generator seeded ``seed + r`` (rank 0: ``seed``,
so one process reproduces the single-GPU run), keeps its generator state in
``checkpoints/step_X.rank{r}.pt``; rank 0 writes checkpoints, snapshots and the model.

Latent caching: target latents are cached in CPU memory (exact: the encoder is deterministic; ~8.7
GB of GPU memory at paper scale otherwise); proxy latents are recomputed each step because the
conditioning noise is added in pixel space. Clips shorter than a fixed window (learned positional
embeddings) are repeated to it (last frame) before encoding.

Augmentation: with ``train.hflip`` each sample is mirrored left-right with probability 1/2 (pixel
space, before encoding; the coin is drawn only when the key is on, so other runs keep their draws).

Timesteps: uniform over [lo, hi] of :func:`schedule.train_timestep_range` (``train.timesteps``).

Objectives: ``diffusion`` (the paper's v-MSE) or ``regression`` (the one-step baseline: the same
network with the proxy latent in both inputs at the fixed timestep ``REGRESSOR_TIMESTEP``, L2
between its x0 estimate and the target latent; no proxy dropout, same conditioning noise).

Snapshots: the transformer weights at the optimizer steps in ``snapshot_steps`` are kept in
``out_dir/candidates/step_XXXXXXX.pt`` for checkpoint selection on validation.
"""

from __future__ import annotations

import json
import logging
import random
import sys
import time
from pathlib import Path

import numpy as np
import torch

from lightcrafter.io import atomic_path, write_text

from .baselines import fit_affine_colour
from .conditioning import drop_proxy_latent, noisy_proxy, sample_log_sigma
from .model import PixelAnchor, Refiner
from .schedule import build_scheduler, train_timestep_range

CKPT_DIR = "checkpoints"
CANDIDATES = "candidates"
LATEST = "latest.txt"
REGRESSOR_TIMESTEP = 999  # fixed timestep input of the one-step regressor
OBJECTIVES = ("diffusion", "regression")


def _logger(out_dir: Path) -> logging.Logger:
    log = logging.getLogger(f"lightcrafter.refiner.train.{out_dir}")
    log.setLevel(logging.INFO)
    if not log.handlers:
        h = logging.FileHandler(out_dir / "train.log")
        h.setFormatter(logging.Formatter("%(asctime)s %(message)s"))
        log.addHandler(h)
    return log


def save_checkpoint(path: Path, state: dict) -> None:
    with atomic_path(path) as tmp:
        torch.save(state, tmp)


def latest_checkpoint(out_dir: Path) -> Path | None:
    f = out_dir / CKPT_DIR / LATEST
    if not f.is_file():
        return None
    p = out_dir / CKPT_DIR / f.read_text().strip()
    return p if p.is_file() else None


def training_loss(model: Refiner, sched, target_lat: torch.Tensor, proxy_lat: torch.Tensor, t: torch.Tensor,
                  noise: torch.Tensor, anchor: torch.Tensor | None = None) -> torch.Tensor:
    """MSE between the model's v and the scheduler's v target at timesteps t (B,).

    ``anchor``: the proxy latent the proxy anchor uses when ``proxy_lat`` is the dropped (zeroed)
    network input -- as in CFG's unconditional branch at inference. Ignored by un-anchored models.
    """
    noisy = sched.add_noise(target_lat, noise, t)
    v_target = sched.get_velocity(target_lat, noise, t)
    if anchor is not None and getattr(model, "proxy_anchor", "none") != "none":
        v_pred = model(noisy, proxy_lat, t, anchor=anchor)
    else:
        v_pred = model(noisy, proxy_lat, t)
    return torch.mean((v_pred - v_target) ** 2)


def anchor_loss(model: Refiner, target_lat: torch.Tensor, proxy_lat: torch.Tensor) -> torch.Tensor:
    """MSE between the learned anchor's map of the proxy latent and the target latent (``train.anchor_loss_weight``):
    what the anchor alone (``infer.residual_scale`` 0) would predict, so it stays a prediction of its own while the
    transformer learns the rest. Zero for a model without a learned anchor."""
    if getattr(model, "anchor_map", None) is None:
        return target_lat.new_zeros(())
    return torch.mean((model.anchor_map(proxy_lat) - target_lat) ** 2)


def regression_x0(model: Refiner, proxy_lat: torch.Tensor) -> torch.Tensor:
    """One-step regressor: x0 estimate of the network with the proxy latent in both inputs."""
    t = torch.full((proxy_lat.shape[0],), REGRESSOR_TIMESTEP, dtype=torch.long, device=proxy_lat.device)
    return model.x0_from_v(proxy_lat, model(proxy_lat, proxy_lat, t), t)


def regression_loss(model: Refiner, target_lat: torch.Tensor, proxy_lat: torch.Tensor) -> torch.Tensor:
    return torch.mean((regression_x0(model, proxy_lat) - target_lat) ** 2)


class PairIndexStream(torch.utils.data.Sampler):
    """Endless pair indices for a DataLoader with worker processes (``train.num_workers`` > 0): uniform
    draws from their own generator seeded ``seed``, starting after ``start`` draws (the number a
    resumed run had consumed; the DataLoader reads ahead, so its state is not the consumed count)."""

    def __init__(self, n: int, seed: int, start: int = 0):
        self.n, self.seed, self.start = int(n), int(seed), int(start)

    def __iter__(self):
        g = torch.Generator().manual_seed(self.seed)
        for _ in range(self.start):
            torch.randint(self.n, (1,), generator=g)
        while True:
            yield int(torch.randint(self.n, (1,), generator=g))


def _index_seed(cfg: dict, rank: int) -> int:
    return (int(cfg["seed"]) + 1) * 1_000_003 + rank


def snapshot_path(out_dir: Path, step: int) -> Path:
    return Path(out_dir) / CANDIDATES / f"step_{step:07d}.pt"


class TargetLatentCache:
    """Exact cache of full-clip target latents in CPU memory, keyed by pair id; ``get`` returns them
    on ``device``."""

    def __init__(self, ae, device=None):
        self.ae, self.store, self.device = ae, {}, device

    def get(self, pair_id: str, video: torch.Tensor) -> torch.Tensor:
        if pair_id not in self.store:
            self.store[pair_id] = self.ae.encode(video[None].to(self.device or video.device)).cpu()
        return self.store[pair_id].to(self.device or video.device)


# Keys that may change between a killed run and its resumption without invalidating it.
_RESUMABLE_CHANGES = {("train", "max_steps"), ("train", "checkpoint_every"), ("train", "log_every"),
                      ("model", "min_ae_round_trip_db")}  # a check before the first step, not part of the state


def run_fingerprint(cfg: dict, dataset, objective: str = "diffusion") -> str:
    """Hash of what a checkpoint's state depends on: the config (bar run-length keys, inference and
    selection keys), the objective, the training timestep range and the data (the dataset's
    ``data_identity()`` when it has one -- re-rendered frames change it -- else the pair ids).

    A checkpoint is only resumed when this matches; otherwise training starts afresh. The running entry
    point's code (lightcrafter.io.CODE_VERSION) counts too: a checkpoint of other code is not resumed.
    """
    from lightcrafter.io import product_fingerprint

    c = {k: (dict(v) if isinstance(v, dict) else v) for k, v in cfg.items()
         if k not in ("infer", "select", "baselines")}
    c["objective"] = objective
    if objective == "diffusion":
        c["timestep_range"] = list(train_timestep_range(cfg))
    for sec, key in _RESUMABLE_CHANGES:
        c.get(sec, {}).pop(key, None)
    if hasattr(dataset, "data_identity"):
        ids = dataset.data_identity()
    else:
        ids = getattr(dataset, "pair_ids", None) or [dataset[i]["pair_id"] for i in range(len(dataset))]
    return product_fingerprint([c, ids])


def train(cfg: dict, dataset, out_dir, *, stop_after: int | None = None, progress: bool = True,
          objective: str = "diffusion", snapshot_steps=(), final_name: str = "model.pt") -> dict:
    """Train (or resume) in ``out_dir``; returns {"losses": [...], "step": int, "seconds_per_step": float (wall
    seconds per optimizer step over the whole training, resumed calls included; also loss_curve.json's),
    "step_seconds": [wall seconds of each optimizer step of this call], "rank": this process's
    data-parallel rank (0 alone writes files)}.

    ``dataset[i]`` -> {"pair_id", "proxy", "target"} with (3, N, H, W) tensors in [-1, 1].
    ``stop_after`` stops after that many optimizer steps of THIS call (simulates a killed job;
    a checkpoint is written first). The final weights go to ``out_dir/final_name``.
    ``objective``: ``diffusion`` | ``regression`` (module docstring). ``snapshot_steps``: optimizer
    steps whose transformer weights are kept as selection candidates (module docstring).
    """
    if objective not in OBJECTIVES:
        raise ValueError(f"objective={objective!r}: use one of {OBJECTIVES}")
    from accelerate import Accelerator

    out_dir = Path(out_dir)
    (out_dir / CKPT_DIR).mkdir(parents=True, exist_ok=True)
    log = _logger(out_dir)
    tr = cfg["train"]
    if tr["batch_size"] != 1:
        raise ValueError("train.batch_size must be 1 (clips of different lengths)")
    if len(dataset) == 0:
        raise ValueError("training set is empty (no pairs with split == 'train')")

    from lightcrafter.devices import resolve_device

    device = resolve_device(cfg["device"], "refiner.device")  # a missing GPU fails before any loading
    torch.manual_seed(cfg["seed"])
    model = Refiner(cfg, training=True)
    if cfg["model"]["kind"] == "tiny":
        n_fit = min(len(dataset), 8)
        model.ae.fit_normalisation(dataset[i]["target"][None] for i in range(n_fit))
    params = model.trainable_parameters()
    groups = [{"params": [p for p in model.transformer.parameters() if p.requires_grad]}]
    if model.anchor_map is not None:  # its own learning rate, no weight decay (it is an identity offset)
        groups.append({"params": list(model.anchor_map.parameters()), "weight_decay": 0.0,
                       "lr": tr["anchor_lr"] if tr["anchor_lr"] is not None else tr["lr"]})
    opt = torch.optim.AdamW(groups, lr=tr["lr"], betas=tuple(tr["adam_betas"]), weight_decay=tr["weight_decay"])
    warm = max(int(tr["warmup_steps"]), 0)
    lr_sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: min(1.0, (s + 1) / warm) if warm else 1.0)
    acc = Accelerator(gradient_accumulation_steps=tr["grad_accum"], cpu=device.type == "cpu", mixed_precision="no")
    rank, main = acc.process_index, acc.is_main_process
    gen = torch.Generator().manual_seed(cfg["seed"] + rank)
    step, losses, drawn = 0, [], 0
    seconds_before = 0.0  # wall seconds of the optimizer steps of earlier (killed or finished) calls

    fingerprint = run_fingerprint(cfg, dataset, objective)
    ckpt = latest_checkpoint(out_dir)
    st = torch.load(ckpt, map_location="cpu", weights_only=False) if ckpt is not None else None
    if st is not None and st.get("fingerprint") != fingerprint:
        log.info("checkpoint %s belongs to another config or data set; training from scratch", ckpt.name)
        st = None
        stale = [*(out_dir / CKPT_DIR).glob("*"), *(out_dir / CANDIDATES).glob("*")]
    elif st is not None and st["step"] > tr["max_steps"]:
        log.info("checkpoint %s is past train.max_steps=%d; training from scratch", ckpt.name, tr["max_steps"])
        st = None
        stale = [*(out_dir / CKPT_DIR).glob("*"), *(out_dir / CANDIDATES).glob("*")]
    else:  # snapshots of an earlier (killed or finished) run with other settings are stale
        stale = list((out_dir / CANDIDATES).glob("*")) if st is None else []
    acc.wait_for_everyone()  # every rank has read the checkpoint before rank 0 removes anything
    if main:
        for old in stale:
            old.unlink(missing_ok=True)
    if st is not None:
        model.load_weights(st)
        model.ae.load_state_dict(st["ae"])
        opt.load_state_dict(st["optimizer"])
        lr_sched.load_state_dict(st["lr_scheduler"])
        own = st if rank == 0 else torch.load(ckpt.with_suffix(f".rank{rank}.pt"), weights_only=False)
        gen.set_state(own["generator"])
        torch.set_rng_state(st["torch_rng"])
        np.random.set_state(st["numpy_rng"])
        random.setstate(st["python_rng"])
        step, losses = st["step"], list(st["losses"])
        seconds_before = st.get("train_seconds")  # None: a checkpoint written before the key was
        drawn = int(own.get("pairs_drawn", 0))
        log.info("resumed from %s at step %d", ckpt.name, step)
    elif cfg["model"]["anchor_init"] == "affine_colour" and isinstance(model.anchor_map, PixelAnchor):
        model.anchor_map.start_at_colour_fit(fit_affine_colour(dataset))  # a fresh start: one pass over the pairs

    dev = acc.device
    model.to(dev)
    if st is None and objective == "diffusion":  # a fresh start checks the autoencoder once (the regressor
        # baseline trains on the same one; a resumed run checked it when it started)
        from .autoencoder import check_round_trip

        ae_source = (f"refiner.model.ae_coeffs {cfg['model']['ae_coeffs']}" if cfg["model"]["kind"] == "tiny"
                     else f"{cfg['model']['model_path']}/vae")
        ae_db = check_round_trip(model.ae, dataset, cfg["model"].get("min_ae_round_trip_db"), ae_source)
        if ae_db is not None:
            log.info("autoencoder round trip on the first training targets: %.2f dB", ae_db)
    model.transformer, opt, lr_sched = acc.prepare(model.transformer, opt, lr_sched)
    acc.step = step * tr["grad_accum"]  # accumulation phase restarts at an optimizer-step boundary
    sched = build_scheduler(cfg, "ddim")
    t_lo, t_hi = train_timestep_range(cfg)
    full_range = (t_lo, t_hi) == (0, sched.config.num_train_timesteps - 1)
    snapshot_steps = {int(s) for s in snapshot_steps}
    cache = TargetLatentCache(model.ae, dev)
    from .frames import pad_to_latent_frames
    model.transformer.train()

    def seconds_so_far() -> float | None:  # of the whole training; None after a checkpoint without the record
        return None if seconds_before is None else seconds_before + time.perf_counter() - t_start

    def checkpoint():
        name = f"step_{step:07d}.pt"
        acc.wait_for_everyone()
        if rank > 0:  # only this rank's generator; rank 0 writes the rest
            save_checkpoint(out_dir / CKPT_DIR / f"step_{step:07d}.rank{rank}.pt",
                            {"generator": gen.get_state(), "pairs_drawn": drawn})
        acc.wait_for_everyone()
        if not main:
            return
        state = {
            **model.weights(acc.unwrap_model(model.transformer)),
            "ae": model.ae.state_dict(),
            "optimizer": opt.state_dict(),
            "lr_scheduler": lr_sched.state_dict(),
            "generator": gen.get_state(),
            "torch_rng": torch.get_rng_state(),
            "numpy_rng": np.random.get_state(),
            "python_rng": random.getstate(),
            "step": step,
            "pairs_drawn": drawn,
            "losses": losses,
            "train_seconds": seconds_so_far(),
            "config": cfg,
            "fingerprint": fingerprint,
        }
        save_checkpoint(out_dir / CKPT_DIR / name, state)
        write_text(out_dir / CKPT_DIR / LATEST, name + "\n")
        keep = {p.name.split(".")[0] for p in sorted((out_dir / CKPT_DIR).glob("step_???????.pt"))[-2:]}
        for old in (out_dir / CKPT_DIR).glob("step_*.pt"):  # keep the last two (and their rank files)
            if old.name.split(".")[0] not in keep:
                old.unlink()

    from tqdm import tqdm

    bar = tqdm(total=tr["max_steps"], initial=step, desc="refiner", disable=not (progress and main), file=sys.stderr)
    done_here, t_start = 0, time.perf_counter()
    window = int(tr["latent_window"])
    pairs = None
    if tr["num_workers"] > 0:  # read pairs in worker processes, ahead of the training step
        import os

        workers = min(int(tr["num_workers"]), max(1, len(os.sched_getaffinity(0)) - 1))  # the data are the same
        loader = torch.utils.data.DataLoader(dataset, batch_size=None, num_workers=workers,
                                             sampler=PairIndexStream(len(dataset), _index_seed(cfg, rank), drawn),
                                             prefetch_factor=2, persistent_workers=False)
        pairs = iter(loader)
    step_seconds = []  # wall seconds of each optimizer step of this call (data, encoding, update)
    while step < tr["max_steps"] and (stop_after is None or done_here < stop_after):
        t_step = time.perf_counter()
        micro = []
        for _ in range(tr["grad_accum"]):
            with acc.accumulate(model.transformer):
                if pairs is not None:
                    item = next(pairs)
                else:
                    item = dataset[int(torch.randint(len(dataset), (1,), generator=gen))]
                drawn += 1
                flip = bool(tr["hflip"]) and bool(torch.rand((), generator=gen) < 0.5)
                if flip:  # mirror proxy and target alike (a mirrored scene is a valid scene)
                    item = {**item, "proxy": item["proxy"].flip(-1), "target": item["target"].flip(-1)}
                if model.fixed_window:  # repeat a short clip to the window the embeddings serve
                    item = {**item, **{k: pad_to_latent_frames(item[k][None], model.fixed_window)[0][0]
                                       for k in ("proxy", "target")}}
                tgt = cache.get(item["pair_id"] + ("#flip" if flip else ""), item["target"].to(dev))
                f = tgt.shape[1]
                s = int(torch.randint(max(f - window, 0) + 1, (1,), generator=gen))
                e = min(f, s + window)
                log_sigma = sample_log_sigma(gen, tr["cond_noise_log_sigma_mean"], tr["cond_noise_log_sigma_std"])
                zp = model.ae.encode(noisy_proxy(item["proxy"][None], log_sigma, gen).to(dev))[:, s:e].float()
                if objective == "regression":
                    loss = regression_loss(model, tgt[:, s:e].float(), zp)
                else:
                    zp_full = zp
                    zp, _ = drop_proxy_latent(zp, tr["proxy_dropout"], gen)
                    if full_range:  # the paper's draw (kept bit-identical to earlier runs)
                        t = torch.randint(sched.config.num_train_timesteps, (1,), generator=gen)
                    else:
                        t = torch.randint(t_lo, t_hi + 1, (1,), generator=gen)
                    noise = torch.randn(zp.shape, generator=gen).to(dev)
                    loss = training_loss(model, sched, tgt[:, s:e].float(), zp, t.to(dev), noise, anchor=zp_full)
                    if tr["anchor_loss_weight"]:
                        loss = loss + tr["anchor_loss_weight"] * anchor_loss(model, tgt[:, s:e].float(), zp_full)
                acc.backward(loss)
                if acc.sync_gradients:
                    if acc.num_processes > 1 and model.anchor_map is not None:  # outside DDP: average by hand
                        for p in model.anchor_map.parameters():
                            p.grad = acc.reduce(p.grad, reduction="mean")
                    acc.clip_grad_norm_(params, tr["max_grad_norm"])
                opt.step()
                lr_sched.step()
                opt.zero_grad()
                micro.append(float(loss.detach()))
        step += 1
        done_here += 1
        step_seconds.append(time.perf_counter() - t_step)
        losses.append(sum(micro) / len(micro))
        bar.update(1)
        bar.set_postfix(loss=f"{losses[-1]:.4f}")
        if step % tr["log_every"] == 0:
            log.info("step %d loss %.6f lr %.3g", step, losses[-1], lr_sched.get_last_lr()[0])
        if step in snapshot_steps and main:
            save_checkpoint(snapshot_path(out_dir, step), {**model.weights(acc.unwrap_model(model.transformer)),
                                                           "step": step, "fingerprint": fingerprint})
        if step % tr["checkpoint_every"] == 0 or step == tr["max_steps"] or done_here == stop_after:
            checkpoint()
    bar.close()
    del pairs  # stops the worker processes
    sec_here = (time.perf_counter() - t_start) / max(done_here, 1)
    # per optimizer step over the whole training, earlier calls included: a call that resumes a finished run (or
    # one killed after its last step) does no step, and its own mean would be the ~0 s of loading the checkpoint
    total = seconds_so_far()
    sec = sec_here if total is None or step == 0 else total / step
    acc.wait_for_everyone()
    if step >= tr["max_steps"] and main:
        save_model(out_dir / final_name, model.weights(acc.unwrap_model(model.transformer)), model.ae, cfg)
        with atomic_path(out_dir / "loss_curve.json") as tmp:
            tmp.write_text(json.dumps({"loss_per_optimizer_step": losses, "seconds_per_optimizer_step": sec}))
    log.info("stopped at step %d (%.3f s/optimizer step this run, %.3f over the whole training)", step, sec_here, sec)
    return {"losses": losses, "step": step, "seconds_per_step": sec, "step_seconds": step_seconds, "rank": rank}


def save_model(path: Path, weights: dict, ae, cfg: dict) -> None:
    """``weights``: :meth:`Refiner.weights` (transformer and, if any, anchor map state dicts)."""
    save_checkpoint(path, {**weights, "ae": ae.state_dict(), "config": cfg})


SELECTED_INFER_KEYS = ("strength", "guidance_scale", "residual_scale", "correction_blur_px",
                       "correction_blur_frames")


def load_model(path, cfg_overrides: dict | None = None, apply_selection: bool = True, device=None) -> Refiner:
    """Rebuild a trained :class:`Refiner` from ``model.pt`` (its stored config, optionally overridden).

    When the file records a validation selection (``selection.chosen``), the chosen ``infer.strength``
    and ``infer.guidance_scale`` are applied after the overrides (``apply_selection=False`` keeps the
    overrides), so a workflow that passes its ``infer`` section still runs what validation picked.
    The selection record is available as ``model.selection`` (None if there was none). The model is
    on ``device`` (default: the config's ``device`` policy, lightcrafter/devices.py).
    """
    from .config import _merge, resolve_config

    from lightcrafter.io import DataError

    fix = "retrain it with train_refiner, or point at a model.pt of this preset"
    try:
        st = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # truncated file, not a torch file, ...
        raise DataError(f"{path}: not a refiner checkpoint ({type(exc).__name__}); {fix}") from None
    if not isinstance(st, dict) or not {"config", "transformer", "ae"} <= set(st):
        raise DataError(f"{path}: not a refiner checkpoint (no config, transformer and ae entries); {fix}")
    cfg = st["config"]
    if cfg_overrides:
        cfg = resolve_config(_merge(cfg, cfg_overrides))
    chosen = (st.get("selection") or {}).get("chosen")
    if apply_selection and chosen:
        cfg = resolve_config(_merge(cfg, {"infer": {k: chosen[k] for k in SELECTED_INFER_KEYS if k in chosen}}))
    model = Refiner(cfg)
    try:
        model.load_weights(st)
        model.ae.load_state_dict(st["ae"])
    except (RuntimeError, KeyError) as exc:  # another architecture: missing / unexpected keys, other shapes
        first = str(exc).strip().splitlines()[0][:160]
        raise DataError(f"{path}: weights of another architecture than the configured refiner ({first}); "
                        f"{fix}") from None
    model.selection = st.get("selection")
    return (model.to_configured_device() if device is None else model.to(device)).eval()
