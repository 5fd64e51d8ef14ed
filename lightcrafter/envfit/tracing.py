"""Environment light transport of R, sampled without looking at the map (Dr.Jit, Mitsuba).

Both solvers estimate R's environment term with the *same* estimator; only when the samples are
drawn differs (fresh every iteration for the reference solver, once for the fast solver).

Per pixel sample (lane), exactly R's set-up (:func:`lightcrafter.proxy.renderer.camera_hit`):
a camera ray through a uniformly jittered point of the pixel footprint (box filter), its hit on
the per-pixel quad mesh of the frame (:func:`lightcrafter.proxy.geometry.pixel_quad_mesh`), the
buffer material of the hit pixel, the two-sided shading normal, and the shadow-ray origin. Then

* surface hit: one direction from the BRDF's own sampling (:func:`lightcrafter.proxy.material.sample`:
  cosine-weighted diffuse + GGX visible normals, map independent), weight f cos / pdf (RGB),
  shadow ray against R's visibility mesh (:meth:`ProxyRenderer.prepare`: the clip aggregate for
  static scenes, the frame's own mesh when objects move); the lane sees the map in that direction.
* camera ray missed and R shows the background: the lane sees the map along the ray, weight 1.

The pixel's radiance is the mean over its lanes of weight x L(direction), and L(direction) is the
bilinear lookup of :mod:`lightcrafter.envmap` (:func:`bilinear_taps` / :func:`bilinear_taps_dr`
give the four texels and weights). Its expectation equals R's (which uses MIS with the map's
importance sampling instead); lights are fixed in the world frame (no per-frame rotation).
Sampler: R's (``multijitter`` stratified per pixel), ``spp`` lanes per pixel, pixel-major.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from lightcrafter.clip import FrameView
from lightcrafter.proxy import material
from lightcrafter.proxy.lighting import Lighting
from lightcrafter.proxy.mitsuba_setup import ensure_variant
from lightcrafter.proxy.renderer import ProxyRenderer, RenderSettings, _stratifiable_count, camera_hit


@dataclass
class Lanes:
    """Dr.Jit arrays of one batch of lanes (pixel-major, ``spp`` consecutive lanes per pixel):
    ``d`` world direction the lane looks up, ``w`` RGB weight (0 for lanes that see nothing)."""

    d: object
    w: object
    spp: int
    pixels: int


def bilinear_taps(d: np.ndarray, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Texel indices (..., 4) (row * W + col) and weights (..., 4) of :func:`lightcrafter.envmap.sample_bilinear`
    at lookup direction(s) ``d`` (..., 3) (numpy, float64)."""
    from lightcrafter.envmap import direction_to_uv

    u, v = direction_to_uv(d)
    col = u * width - 0.5
    row = np.clip(v * height - 0.5, 0.0, height - 1.0)
    c0 = np.floor(col).astype(np.int64)
    r0 = np.floor(row).astype(np.int64)
    fc, fr = col - c0, row - r0
    c1 = (c0 + 1) % width
    c0 = c0 % width
    r1 = np.minimum(r0 + 1, height - 1)
    idx = np.stack([r0 * width + c0, r0 * width + c1, r1 * width + c0, r1 * width + c1], axis=-1)
    wts = np.stack([(1 - fc) * (1 - fr), fc * (1 - fr), (1 - fc) * fr, fc * fr], axis=-1)
    return idx, wts


def bilinear_taps_dr(d, height: int, width: int):
    """Dr.Jit twin of :func:`bilinear_taps`: ([4 x UInt32 texel index], [4 x Float weight])."""
    n = dr.norm(d)
    n = dr.select(n > 0, n, 1.0)
    x, y, z = d.x / n, d.y / n, d.z / n
    u = (math.pi - dr.atan2(y, x)) * (1.0 / (2.0 * math.pi))
    u = u - dr.floor(u)
    v = dr.acos(dr.clip(z, -1.0, 1.0)) * (1.0 / math.pi)
    col = u * width - 0.5
    row = dr.clip(v * height - 0.5, 0.0, height - 1.0)
    c0f, r0f = dr.floor(col), dr.floor(row)
    fc, fr = col - c0f, row - r0f
    c0 = mi.Int32(c0f)
    r0 = mi.Int32(r0f)
    c1 = dr.select(c0 + 1 >= width, c0 + 1 - width, c0 + 1)
    c0 = dr.select(c0 < 0, c0 + width, c0)
    r1 = dr.minimum(r0 + 1, height - 1)
    idx = [mi.UInt32(r0 * width + c0), mi.UInt32(r0 * width + c1),
           mi.UInt32(r1 * width + c0), mi.UInt32(r1 * width + c1)]
    wts = [(1 - fc) * (1 - fr), fc * (1 - fr), (1 - fc) * fr, fc * fr]
    return idx, wts


class Tracer:
    """Samples R's environment transport on the frames of one clip.

    ``settings``: R's render settings (geometry, visibility, sampler); visibility must already be
    resolved ('aggregate' for static scenes, see lightcrafter.proxy.clip.resolve_visibility).
    ``cache_frames`` keeps each frame's primary geometry (the reference solver revisits frames).
    """

    def __init__(self, views: list[FrameView], settings: RenderSettings, cache_frames: bool = False):
        ensure_variant()
        self.settings = settings
        self.renderer = ProxyRenderer(Lighting(env=None), settings)
        self.renderer.prepare(views)
        self.cache_frames = cache_frames
        self._states: dict = {}

    def state(self, view: FrameView):
        key = view.cache_key()
        if key in self._states:
            return self._states[key]
        st = self.renderer.frame_state(view)
        if self.cache_frames:
            self._states[key] = st
        return st

    def lanes(self, view: FrameView, pixels: np.ndarray, spp: int, seed: int) -> Lanes:
        """Trace ``spp`` lanes for each flat pixel index in ``pixels`` (row * W + col) of ``view``."""
        s = self.settings
        prim, shadow = self.state(view)
        spp = _stratifiable_count(s.sampler, max(1, int(spp)))
        npix = len(pixels)
        lanes = npix * spp
        if s.sampler != "independent" and spp > 1:
            sampler = mi.load_dict({"type": s.sampler, "sample_count": spp})
            sampler.set_samples_per_wavefront(spp)
        else:
            sampler = mi.load_dict({"type": "independent"})
        sampler.seed(dr.opaque(mi.UInt32, int(seed) % (1 << 32)), lanes)
        pix_arr = mi.UInt32(np.ascontiguousarray(pixels, np.uint32))
        idx = dr.arange(mi.UInt32, lanes)
        pix = dr.gather(mi.UInt32, pix_arr, idx // spp)
        col = mi.Float(pix % prim.width)
        row = mi.Float(pix // prim.width)
        jit = sampler.next_2d()
        pos = mi.Point2f((col + jit.x) / prim.width, (row + jit.y) / prim.height)
        ray, si, hit, albedo, rough, metal, frame, wo, p0 = camera_hit(prim, pos, s.shadow_offset_px)
        wi, w_b, pdf = material.sample(albedo, rough, metal, wo, sampler.next_1d(), sampler.next_2d())
        d_surf = frame.to_world(wi)
        act = hit & (pdf > 0)
        vis = ~shadow.ray_test(mi.Ray3f(p0, d_surf), act)
        surf = act & vis
        w = dr.select(surf, w_b, mi.Color3f(0.0))
        if s.show_background:
            w = dr.select(hit, w, mi.Color3f(1.0))
        d = dr.select(hit, d_surf, ray.d)
        dr.eval(d, w)
        return Lanes(d=d, w=w, spp=spp, pixels=npix)
