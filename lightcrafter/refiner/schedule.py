"""CogVideoX noise-schedule parameterisation, set explicitly (never the diffusers class defaults).

The class defaults of ``CogVideoXDDIMScheduler``/``CogVideoXDPMScheduler`` (epsilon prediction,
``leading`` spacing, ``snr_shift_scale`` 3.0) differ from the CogVideoX-5B checkpoint's
``scheduler_config.json`` (v-prediction, ``trailing``, zero terminal SNR, shift 1.0). With zero
terminal SNR, alpha_bar(t=999) = 0: an epsilon objective would divide by zero there, while the
v target ``sqrt(ab) * eps - sqrt(1 - ab) * x0`` stays finite (= -x0).
"""

from __future__ import annotations

import json
from pathlib import Path

from .config import COGVIDEOX_5B_SCHEDULER


def scheduler_config(cfg: dict) -> dict:
    """The scheduler kwargs of a run: the local checkpoint's file if present, else ``cfg['scheduler']``."""
    path = cfg["model"].get("model_path")
    if path:
        f = Path(path) / "scheduler" / "scheduler_config.json"
        if f.is_file():
            data = json.loads(f.read_text())
            return {k: v for k, v in data.items() if not k.startswith("_") and k in COGVIDEOX_5B_SCHEDULER}
    return dict(cfg.get("scheduler") or COGVIDEOX_5B_SCHEDULER)


def build_scheduler(cfg: dict, sampler: str | None = None):
    """A fresh CogVideoX scheduler (``ddim`` or ``dpm``) with the run's parameterisation.

    ``timestep_spacing`` is forced to ``trailing`` at inference as in the paper, whatever the file says.
    """
    from diffusers import CogVideoXDDIMScheduler, CogVideoXDPMScheduler

    kwargs = scheduler_config(cfg)
    kwargs["timestep_spacing"] = "trailing"
    sampler = sampler or cfg["infer"]["sampler"]
    cls = {"ddim": CogVideoXDDIMScheduler, "dpm": CogVideoXDPMScheduler}.get(sampler)
    if cls is None:
        raise ValueError(f"infer.sampler={sampler!r}: use 'ddim' or 'dpm'")
    sched = cls(**kwargs)
    if sched.config.prediction_type != "v_prediction":
        raise ValueError(f"scheduler prediction_type={sched.config.prediction_type!r}; the refiner is v-prediction")
    return sched


def max_strength(cfg: dict) -> float:
    """The largest SDEdit strength inference may use: infer.strength and, when validation selection
    is on, every candidate in select.strengths."""
    vals = [float(cfg["infer"].get("strength", 1.0))]
    if float(cfg.get("select", {}).get("val_scenes", 0) or 0) > 0:
        vals += [float(s) for s in cfg["select"]["strengths"]]
    return max(vals)


def train_timestep_range(cfg: dict) -> tuple[int, int]:
    """Inclusive [lo, hi] range training draws timesteps from (``train.timesteps``).

    ``all``: every training step [0, num_train_timesteps - 1] (paper). ``sampler_range``: from the last
    timestep the sampler visits at ``infer.num_steps`` (trailing spacing) up to the first timestep it
    visits at :func:`max_strength` -- the range where the model is ever asked for a prediction. Below
    lo the v-MSE weight 1 / (1 - abar_t) of an x0-anchored model grows to ~1200 at t = 0.
    """
    from .sampler import kept_timesteps

    sched = build_scheduler(cfg, "ddim")
    n_train = int(sched.config.num_train_timesteps)
    if cfg["train"].get("timesteps", "all") == "all":
        return 0, n_train - 1
    steps = int(cfg["infer"]["num_steps"])
    sched.set_timesteps(steps)
    kept = kept_timesteps(sched.timesteps, steps, max_strength(cfg))
    if len(kept) == 0:  # strength so small that no step runs: train where the last step would be
        kept = sched.timesteps[-1:]
    return int(kept[-1]), int(kept[0])
