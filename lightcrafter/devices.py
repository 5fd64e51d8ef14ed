"""One device policy for the torch stages (the refiner and its baselines, the G-buffer estimator).

A stage's ``device`` key is one of

* ``cpu``: always the CPU (the tiny refiner preset and the estimator's default: bit-reproducible on
  any machine);
* ``cuda``: a CUDA GPU, or a one-line error when torch sees none (the paper preset: a 5B model never
  falls back to the CPU silently, where one clip takes tens of hours);
* ``auto``: CUDA when torch sees a GPU, else the CPU -- unless the job was *given* a GPU (SLURM
  exported ``SLURM_GPUS_ON_NODE`` / ``SLURM_JOB_GPUS`` / ``CUDA_VISIBLE_DEVICES`` with a device) and
  torch cannot see it (a CPU-only torch build, a driver mismatch): that is the same one-line error,
  because a job the profile sent to a GPU node must not run on its CPU.

Under ``accelerate launch`` / torchrun each process takes ``cuda:{LOCAL_RANK}``.
"""

from __future__ import annotations

import os

from .errors import NoGPUError  # noqa: F401  (defined there, so that scripts/_cli.py imports nothing else)

DEVICES = ("auto", "cpu", "cuda")
_GPU_ENV = ("SLURM_GPUS_ON_NODE", "SLURM_JOB_GPUS", "CUDA_VISIBLE_DEVICES")


def allocated_gpus() -> str | None:
    """The environment variable (``NAME=value``) that says this job was given a GPU, or None."""
    for name in _GPU_ENV:
        v = os.environ.get(name, "").strip()
        none = ("", "-1", "NoDevFiles") if name == "CUDA_VISIBLE_DEVICES" else ("", "0")
        if v not in none:
            return f"{name}={v}"
    return None


def resolve_device(want: str, key: str = "device"):
    """The ``torch.device`` of a stage whose config ``key`` is ``want`` (module docstring)."""
    import torch

    if want not in DEVICES:
        raise ValueError(f"{key}={want!r}: use one of {DEVICES}")
    if want == "cpu":
        return torch.device("cpu")
    if torch.cuda.is_available():
        return torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")))
    given = allocated_gpus()
    if want == "cuda" or given:
        why = f"the job was given a GPU ({given}) but " if given else ""
        raise NoGPUError(
            f"{key}={want}: {why}torch {torch.__version__} sees no CUDA GPU (torch.version.cuda="
            f"{torch.version.cuda}); run on a GPU node with a CUDA build of torch, or set {key}: cpu")
    return torch.device("cpu")
