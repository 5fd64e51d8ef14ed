"""The paper's reconstruction stack Phi as a backend (GPU cluster path): MegaSAM (cameras + depth),
DiffusionRenderer (G-buffers), DiffusionLight (lighting), run by configured commands.

Modules (one job each):

* :mod:`.megasam` -- MegaSAM's ``*_sgd_cvd_hr.npz`` -> z-depth, per-frame K, c2w in our world
  (X = x, Y = z, Z = -y of the first OpenCV camera); MegaSAM's working pixel grid.
* :mod:`.diffusion_renderer` -- the inverse renderer's 8-bit pass images -> linear albedo,
  roughness, metallic, world normals (and relative depth, for checking), resampled onto the clip grid.
* :mod:`.diffusion_light` -- the camera-aligned lat-long HDR -> our world envmap convention.
* :mod:`.backend` -- :func:`~.backend.reconstruct_paper_stack`: runs the three command templates,
  checks them, and writes a clip (lightcrafter.clip) plus ``envmap_init.exr``.

Each module docstring lists the native format with the public repository and files it was read
from, and what could not be verified there. The adapters are pure numpy (plus file reading); none of
the tools is imported or needed to run the tests.
"""

from lightcrafter.recon.paper_stack.backend import ToolError, reconstruct_paper_stack

__all__ = ["ToolError", "reconstruct_paper_stack"]
