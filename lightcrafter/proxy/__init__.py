"""Forward renderer R(S, L): PBR proxy videos from buffers with Mitsuba 3.

Modules (one job each): :mod:`.geometry` (unprojection, per-pixel meshes), :mod:`.visibility`
(clip shadow mesh, pymeshlab), :mod:`.material` (the paper's BRDF), :mod:`.lighting` (envmap +
local lights), :mod:`.camera` (OpenCV -> Mitsuba sensor), :mod:`.renderer` (the integrator),
:mod:`.edits` (material edits), :mod:`.clip` (a clip from files on disk to frames, video, manifest),
:mod:`.mitsuba_setup` (variant), :mod:`.cycles_scene` (the same proxy scene in Blender Cycles, for
the convention test and benchmarks), :mod:`.synthetic` (analytic sphere/plane buffers for tests).
"""


def render_settings(proxy: dict | None = None, **overrides):
    """R's settings (:class:`.renderer.RenderSettings`) from config ``proxy`` (lightcrafter.config.models.Proxy):
    the one place every rule that renders with R (synthetic and ground-truth proxies, envmap fitting and
    pseudo-inputs, MIT, long form, edits) gets them from, so real and synthetic proxies share one R.
    Missing keys take the model's defaults; ``overrides`` replace RenderSettings fields (tests, benchmarks)."""
    from dataclasses import replace

    from lightcrafter.config import validate_section
    from lightcrafter.config.models import Proxy
    from lightcrafter.proxy.renderer import RenderSettings
    from lightcrafter.proxy.visibility import VisibilitySettings

    p = validate_section(Proxy, proxy, "proxy")
    shadow_cut = p.visibility_rel_threshold or p.rel_threshold  # the shadow meshes' cut (null: the camera quads')
    s = RenderSettings(spp=p.spp, seed=p.seed, rel_threshold=p.rel_threshold, border_px=p.border_px,
                       bilateral_sigma_px=p.bilateral_sigma_px, visibility=p.visibility, sampler=p.sampler,
                       denoiser=p.denoiser,
                       visibility_mesh=VisibilitySettings(rel_threshold=shadow_cut, max_faces=p.visibility_max_faces))
    return replace(s, **overrides) if overrides else s
