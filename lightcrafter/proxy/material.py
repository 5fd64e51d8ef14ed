"""The paper's BRDF (eq. cook_torrance), evaluated and sampled in Dr.Jit (Mitsuba variant types).

    f(wi, wo) = (1 - m) a / pi  +  D G F / (4 (wo.n) (wi.n))

* ``a`` linear base colour (RGB), ``m`` metallic, ``r`` roughness, all in [0, 1].
* D: GGX (Trowbridge-Reitz) with alpha = max(r^2, ALPHA_MIN) (Karis 2013 remapping). r = 0 is
  therefore a very sharp but finite lobe (alpha 1e-3, like Mitsuba's principled), never a delta.
* G: separable Smith masking-shadowing for GGX, G = G1(wi) G1(wo) (Walter et al. 2007).
* F: Schlick, F0 = lerp(0.04, a, m), evaluated at the half vector.

Why a custom BRDF and not Mitsuba's ``principled``: principled uses Burley diffuse with a
retro-reflection term, a specular tint/"specular" parameter (metallic with specular 0 renders
black) and is one-sided; the paper's model is Lambert + Cook-Torrance, exactly the formula above.
It is evaluated inside our own integrator (``renderer.py``) from per-pixel buffers, so no per-vertex
attribute textures are needed and pixels keep their exact buffer materials.

The model is *not* energy conserving for bright dielectrics (the diffuse lobe is not reduced by
the Fresnel reflectance, as in Karis 2013): its directional albedo is (1 - m) a + E_spec with
E_spec ~ 0.04 at normal incidence. Metals (single-scatter GGX) reflect <= 1.

All directions are unit vectors in the local shading frame (normal = +z). Grazing and
back-facing inputs are handled without division by zero: cosines are clamped to COS_MIN, and
wi/wo below the surface give f = 0.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

ALPHA_MIN = 1e-3  # GGX alpha floor (roughness ~ 0.032)
COS_MIN = 1e-4  # smallest cosine used in denominators
F0_DIELECTRIC = 0.04
INV_PI = 0.3183098861837907


def alpha_of(roughness):
    """GGX alpha from perceptual roughness r in [0, 1]: max(r^2, ALPHA_MIN)."""
    r = dr.clip(roughness, 0.0, 1.0)
    return dr.maximum(r * r, ALPHA_MIN)


def ggx_d(cos_h, alpha):
    """GGX normal distribution D(h) for cos(theta_h) (local z of the half vector)."""
    a2 = alpha * alpha
    c2 = dr.clip(cos_h * cos_h, 0.0, 1.0)
    t = c2 * (a2 - 1.0) + 1.0
    return dr.select(cos_h > 0, a2 / (dr.pi * t * t), 0.0)


def smith_g1(cos_v, alpha):
    """Smith masking for GGX (Walter 2007): 2 / (1 + sqrt(1 + alpha^2 tan^2 theta))."""
    c2 = dr.maximum(cos_v * cos_v, COS_MIN * COS_MIN)
    tan2 = dr.maximum(1.0 - c2, 0.0) / c2
    return dr.select(cos_v > 0, 2.0 / (1.0 + dr.sqrt(1.0 + alpha * alpha * tan2)), 0.0)


def fresnel_schlick(f0, cos_d):
    c = dr.clip(1.0 - cos_d, 0.0, 1.0)
    c2 = c * c
    return f0 + (1.0 - f0) * (c2 * c2 * c)


def f0_of(albedo, metallic):
    return dr.lerp(mi.Color3f(F0_DIELECTRIC), albedo, metallic)


def _half(wo, wi):
    h = wo + wi
    n = dr.norm(h)
    return dr.select(n > 1e-12, h / dr.maximum(n, 1e-12), mi.Vector3f(0, 0, 1))


def eval_cos(albedo, roughness, metallic, wo, wi):
    """f(wi, wo) * max(0, wi.n) as Color3f (the integrand without the incident radiance)."""
    alpha = alpha_of(roughness)
    cos_o = dr.maximum(wo.z, COS_MIN)
    cos_i = wi.z
    active = (wo.z > 0) & (cos_i > 0)
    h = _half(wo, wi)
    d = ggx_d(h.z, alpha)
    g = smith_g1(cos_o, alpha) * smith_g1(cos_i, alpha)
    f = fresnel_schlick(f0_of(albedo, metallic), dr.maximum(dr.dot(wo, h), 0.0))
    spec = f * (d * g / (4.0 * cos_o))  # the (wi.n) of the denominator cancels with the cosine
    diff = albedo * ((1.0 - metallic) * INV_PI * dr.maximum(cos_i, 0.0))
    return dr.select(active, diff + spec, mi.Color3f(0.0))


def _spec_probability(albedo, metallic, wo):
    s = mi.luminance(fresnel_schlick(f0_of(albedo, metallic), dr.maximum(wo.z, 0.0)))
    d = mi.luminance(albedo * (1.0 - metallic))
    p = dr.select(s + d > 0, s / dr.maximum(s + d, 1e-12), 0.5)
    return dr.select(d > 0, dr.clip(p, 0.1, 0.9), 1.0)


def pdf(albedo, roughness, metallic, wo, wi):
    """Solid-angle density of :func:`sample` (mixture of cosine and GGX visible-normal sampling)."""
    alpha = alpha_of(roughness)
    ps = _spec_probability(albedo, metallic, wo)
    cos_o = dr.maximum(wo.z, COS_MIN)
    h = _half(wo, wi)
    p_spec = smith_g1(cos_o, alpha) * ggx_d(h.z, alpha) / (4.0 * cos_o)
    p_diff = dr.maximum(wi.z, 0.0) * INV_PI
    return dr.select((wi.z > 0) & (wo.z > 0), ps * p_spec + (1.0 - ps) * p_diff, 0.0)


def sample(albedo, roughness, metallic, wo, u1, u2):
    """Sample wi; return (wi, weight = f cos / pdf, pdf). ``u1`` Float, ``u2`` Point2f in [0, 1)."""
    alpha = alpha_of(roughness)
    ps = _spec_probability(albedo, metallic, wo)
    # diffuse: cosine-weighted hemisphere
    wi_d = mi.warp.square_to_cosine_hemisphere(u2)
    # specular: GGX visible normals (Heitz 2018), reflected about the sampled microfacet normal
    wo_c = mi.Vector3f(wo.x, wo.y, dr.maximum(wo.z, COS_MIN))
    vh = dr.normalize(mi.Vector3f(alpha * wo_c.x, alpha * wo_c.y, wo_c.z))
    lensq = vh.x * vh.x + vh.y * vh.y
    t1 = dr.select(lensq > 1e-14, mi.Vector3f(-vh.y, vh.x, 0.0) * dr.rsqrt(dr.maximum(lensq, 1e-14)),
                   mi.Vector3f(1.0, 0.0, 0.0))
    t2 = dr.cross(vh, t1)
    r = dr.sqrt(u2.x)
    phi = 2.0 * dr.pi * u2.y
    p1 = r * dr.cos(phi)
    p2 = r * dr.sin(phi)
    s = 0.5 * (1.0 + vh.z)
    p2 = (1.0 - s) * dr.sqrt(dr.maximum(1.0 - p1 * p1, 0.0)) + s * p2
    nh = p1 * t1 + p2 * t2 + dr.sqrt(dr.maximum(1.0 - p1 * p1 - p2 * p2, 0.0)) * vh
    m = dr.normalize(mi.Vector3f(alpha * nh.x, alpha * nh.y, dr.maximum(nh.z, 1e-6)))
    wi_s = 2.0 * dr.dot(wo_c, m) * m - wo_c
    wi = dr.select(u1 < ps, wi_s, wi_d)
    wi = dr.normalize(wi)
    p = pdf(albedo, roughness, metallic, wo, wi)
    val = eval_cos(albedo, roughness, metallic, wo, wi)
    ok = (p > 0) & (wi.z > 0) & (wo.z > 0)
    weight = dr.select(ok, val / dr.maximum(p, 1e-20), mi.Color3f(0.0))
    return wi, weight, dr.select(ok, p, 0.0)
