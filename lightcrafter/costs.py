"""Projected CPU cost of a configuration from a measured run (the report's "projected core-hours").

Model: each CPU stage's cost is proportional to a unit of work that both configurations define from
their plans alone (no rendering): for example Cycles radiance costs CPU seconds per (frame x pixel x
sample). The measured run gives CPU seconds per unit (from the rules' Snakemake benchmark files); the
projection multiplies by the other configuration's units. Per-job start-up costs are folded into the
unit rate, so projecting to much larger frames over-counts them slightly. Stages that run on GPUs at
the paper's scale (the paper stack's reconstruction, refiner training and inference) are not projected
from CPU timings; the paper reports 48 GPU-hours of refiner training.
"""

from __future__ import annotations

from .scenes import denoise_networks, rendered_plans


def units(cfg: dict) -> dict[str, tuple[str, float, int]]:
    """{stage: (unit name, units, jobs)} of a configuration, from its plans."""
    s = cfg["scenes"]
    px = s["width"] * s["height"]
    n = s["num_frames"]
    plans = rendered_plans(cfg)
    trajs = [(p["split"], t) for p in plans for t in p["trajectories"]]
    rgb_jobs = sum(len(t["render_lights"]) for _, t in trajs)
    pairs = sum(len(t["target_lights"]) for sp, t in trajs if sp in ("train", "test"))
    refiner_trajs = [t for sp, t in trajs if sp in ("train", "test")]
    spp, pspp = cfg["render"]["spp"], cfg["proxy"]["spp"]
    real = sum(len(v.get("start_frames") or []) or int(v.get("clips", 1)) for v in cfg.get("real", {}).get("videos", []))
    d = cfg.get("real", {}).get("dl3dv") or {}
    if d.get("root"):  # planned DL3DV clips (the folder need not exist where the report is built)
        real += int(d.get("max_scenes") or 0) * int(d.get("clips_per_scene", 1))
    return {
        "sample_scene": ("scenes", len(plans), len(plans)),
        "render_rgb": ("frame x megapixel x spp", rgb_jobs * n * px / 1e6 * spp, rgb_jobs),
        "render_buffers": ("buffer frame x megapixel", sum(t["buffer_frames"] for _, t in trajs) * px / 1e6, len(trajs)),
        "render_proxy_gt": ("frame x megapixel x spp", pairs * n * px / 1e6 * pspp, pairs),
        "render_proxy": ("frame x megapixel x spp", pairs * n * px / 1e6 * pspp, pairs),
        "reconstruct_synthetic": ("frame x megapixel", len(refiner_trajs) * n * px / 1e6, len(refiner_trajs)),
        "align_synthetic": ("frame x megapixel", len(refiner_trajs) * n * px / 1e6, len(refiner_trajs)),
        "ingest_video": ("frame x megapixel", real * n * px / 1e6, real),
        "fit_envmap": ("clips", real, real),
    }


def denoiser_networks(cfg: dict) -> tuple[str, str]:
    """(OIDN network of the videos Phi sees, of target-only videos) that a configuration's Cycles renders use."""
    r = cfg.get("render", {})
    return denoise_networks(r) if r.get("denoiser", "none") == "oidn" else ("none", "none")


GPU_AT_PAPER_SCALE = {"train_refiner": "GPU (CogVideoX-5B); the paper reports 48 GPU-hours",
                      "infer_refiner": "GPU (about 8 min per 49-frame clip on an A6000, paper)",
                      "reconstruct_real": "GPU with recon.backend paper_stack (MegaSAM, DiffusionRenderer)",
                      "train_gbuffer_estimator": "not used with the paper stack"}


def project(measured: list[dict], run_cfg: dict, target_cfg: dict) -> dict:
    """Project per-stage CPU core-hours of ``target_cfg`` from ``measured`` (report.stage_costs of a run of
    ``run_cfg``)."""
    u_run, u_tgt = units(run_cfg), units(target_cfg)
    by_stage = {m["stage"]: m for m in measured}
    stages, total = [], 0.0
    for stage, (unit, n_tgt, jobs) in u_tgt.items():
        m = by_stage.get(stage)
        n_run = u_run[stage][1]
        if m is None or not n_run:
            stages.append({"stage": stage, "jobs": jobs, "unit": unit, "units": round(n_tgt, 2), "core_hours": None,
                           "note": "not measured in this run"})
            continue
        if stage == "reconstruct_synthetic" and target_cfg.get("recon", {}).get("backend") == "paper_stack":
            stages.append({"stage": stage, "jobs": jobs, "unit": unit, "units": round(n_tgt, 2), "core_hours": None,
                           "note": "GPU with recon.backend paper_stack (MegaSAM, DiffusionRenderer, DiffusionLight)"})
            continue
        ch = m["cpu_s"] / n_run * n_tgt / 3600
        total += ch
        note = f"{m['cpu_s'] / n_run:.3g} CPU s per unit measured here"
        if stage == "render_rgb" and denoiser_networks(run_cfg) != denoiser_networks(target_cfg):
            note += ("; OIDN networks differ (this run: {}, projected: {}): the measured rate is not the projected "
                     "run's".format(*(", ".join(denoiser_networks(c)) for c in (run_cfg, target_cfg))))
        stages.append({"stage": stage, "jobs": jobs, "unit": unit, "units": round(n_tgt, 2), "core_hours": round(ch, 2),
                       "note": note})
    for stage, note in GPU_AT_PAPER_SCALE.items():
        stages.append({"stage": stage, "jobs": None, "unit": "", "units": None, "core_hours": None, "note": note})
    return {"method": __doc__.split("\n\n")[1].replace("\n", " "), "stages": stages,
            "total_core_hours": round(total, 1)}
