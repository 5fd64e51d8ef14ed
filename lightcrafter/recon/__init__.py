"""The reconstruction stack Phi: a video in, a clip (lightcrafter.clip) of estimated buffers + cameras out.

One contract for every backend::

    Phi(video frames, fps, intrinsics prior) -> clip folder: buffers/ (z-depth, world normals, linear
    base colour, roughness, metallic, mask), cameras.json (per-frame K, c2w; OpenCV camera axes, a
    world of the backend's choosing, Z up where it can tell), buffers.json (units "arbitrary": one
    unknown scale per clip), optionally confidence/

The same Phi runs on the source video of every synthetic trajectory (once per trajectory, not per
target light) and on every real clip, so synthetic and real proxies carry the same artifacts.

Backends (config ``recon.backend``), looked up in :data:`BACKENDS`:

* ``default`` (:mod:`.default`): CPU, nothing downloaded, estimates from pixels only -- COLMAP
  structure from motion through pycolmap for cameras (:mod:`.cameras`), and a small G-buffer
  estimator trained by the pipeline on the recon split's ground truth (:mod:`.estimator`);
* ``paper_stack`` (:mod:`.paper_stack`): the paper's MegaSAM + DiffusionRenderer + DiffusionLight,
  run by user-configured commands on a GPU cluster, converted by adapters.

Synthetic clips are then brought into the ground-truth frame by :mod:`.align` (a global similarity
and a depth scale; local errors are kept).
"""

BACKENDS = {
    "default": "lightcrafter.recon.default:reconstruct_default",
    "paper_stack": "lightcrafter.recon.paper_stack:reconstruct_paper_stack",
}


def backend(name: str):
    """The reconstruct function of backend ``name`` (imported on use)."""
    import importlib

    if name not in BACKENDS:
        raise ValueError(f"recon.backend={name!r}: use one of {sorted(BACKENDS)}")
    module, func = BACKENDS[name].split(":")
    return getattr(importlib.import_module(module), func)
