"""Evaluation metrics of the paper and their aggregation (one module; scripts only call it).

Inputs
------
Every metric works on DISPLAY videos: float arrays shaped (N, H, W, 3) with values in [0, 1],
obtained from linear radiance only through :func:`lightcrafter.io.linear_to_display` with the same
exposure for the method and the target. A video outside [0, 1] (tolerance 1e-6) or with a shape that
differs from its reference raises ``ValueError``.

Metrics
-------
Reference metrics, frame-wise against the ground-truth (target) video, then the mean over frames
gives one value per clip:

* **PSNR** (dB, higher is better): ``skimage.metrics.peak_signal_noise_ratio`` with data_range 1
  on all three channels, 10 log10(1 / MSE). Identical frames give +inf; each frame's value is
  capped at :data:`PSNR_CAP_DB` = 100 dB before the mean so means stay finite.
* **SSIM** (higher is better): ``skimage.metrics.structural_similarity`` with the settings of
  Wang et al. 2004 (:data:`SSIM_SETTINGS`): Gaussian window sigma = 1.5 px truncated at 3.5 sigma
  (11 taps), population (not sample) covariance, K1 = 0.01, K2 = 0.03, data_range 1, computed per
  channel (``channel_axis``) and averaged over channels; the 5-px border where the window leaves
  the image is excluded from the mean (scikit-image's convention), borders filtered in 'reflect'.
* **LPIPS** (lower is better): LPIPS v0.1 (Zhang et al. 2018, AlexNet backbone by default) in plain
  torch (:mod:`lightcrafter.lpips_net`: no torchvision, no ``lpips`` package) on frames scaled to
  [-1, 1], per frame, then the mean. Both weight files (torchvision's backbone checkpoint and the v0.1
  linear layers) come only from a configured local folder (never downloaded; :func:`load_lpips`).
  Without them the result is marked "not computed: <reason>" and carries no value.

Temporal metrics, one value per transition t -> t+1, then the mean over transitions:

* **Warp-SSIM** (higher is better; structural consistency after optical-flow warping). Optical flow
  is computed on a REFERENCE video (the target for synthetic pairs, the original input video for
  real clips without a target) with OpenCV's DIS
  optical flow, preset MEDIUM (:data:`FLOW_PRESET`; 8-bit luma, BT.601 weights), forward
  f: t -> t+1 and backward b: t+1 -> t. A pixel x of frame t is kept when x + f(x) lies inside the
  image and passes the forward-backward consistency check of Sundaram et al. 2010,
  |f(x) + b(x + f(x))|^2 < alpha (|f(x)|^2 + |b(x + f(x))|^2) + beta, alpha = 0.01, beta = 0.5 px^2
  (:data:`OCCLUSION_ALPHA`, :data:`OCCLUSION_BETA`). The METHOD's frame t+1 is warped back to t,
  warped(x) = method[t+1](x + f(x)) (``cv2.remap``, bilinear), and the SSIM map (settings above,
  ``full=True``, averaged over channels) between warped and method[t] is averaged over the kept
  pixels (the 5-px image border excluded as for SSIM). A pixel on a motion boundary
  (|grad f_x|^2 + |grad f_y|^2 > 0.01 |f|^2 + 0.002, the second test of Sundaram et al.) is dropped
  too: DIS smears a moving object's motion a few pixels onto the background it covers, where the
  forward and backward flows then agree. Even so about a third of such a covered band survives (a
  32-px square moving 6 px/frame over a textured background: a perfect method scores 0.984 masked,
  0.947 unmasked), and SSIM windows next to a kept/dropped boundary still see a few dropped
  pixels. The per-transition curve and the kept fraction per transition are returned with the mean.
* **T-CLIP** (higher is better; temporal smoothness): cosine similarity of CLIP image embeddings
  of adjacent frames, mean over transitions (``pairs="all"`` gives the all-pairs mean some papers
  report as "CLIP frame consistency"). Embeddings come from a LOCAL Hugging Face ``transformers``
  CLIP folder (``config.json``, weights, ``preprocessor_config.json``; e.g. a saved
  ``openai/clip-vit-base-patch32``), frames passed as 8-bit images through the folder's
  ``CLIPImageProcessorPil`` (resize shortest side, centre crop, CLIP normalisation) and
  ``vision_model`` + ``visual_projection``. Nothing is downloaded: with no folder configured, or a
  path that does not exist, the result is "not computed: no CLIP weights at <path>".

Which video the flow comes from. The paper takes Warp-SSIM "from Light-X"; the public Light-X
repository holds no evaluation code, so its exact protocol could not be checked. The closest public
implementation (TC-Light's ``evaluate.py``, a relighting paper reporting "Warp SSIM") computes RAFT
flow on the source/ground-truth video, not on the method's output, masks occlusions with a
forward-backward check (norms, alpha = beta = 0.5) and then scores SSIM over the whole frame with
occluded pixels zeroed in both images. Here the flow comes from the reference video as well (so a
method cannot score well by producing a static or blurry video whose own flow is trivial), but
occluded pixels are excluded from the average instead of being counted as perfect matches, and DIS
replaces RAFT (no network weights). Numbers are therefore comparable between our methods, not to
the digit with published tables.

Aggregation
-----------
**The registry** (:data:`METRICS`): each metric is one :class:`Metric` entry (name, label, direction,
needs-reference, function of the video and a :class:`Context`); ``scripts/evaluate_refiner.py`` computes
every entry for every method (:func:`evaluate_video`) and the no-reference ones on the target too
(:func:`evaluate_target`), and the report takes its labels and directions from it.

Per clip: the mean over frames (or transitions); per method, the mean over clips. Uncertainty: :func:`bootstrap_ci`
(percentile bootstrap of the mean over clips) and :func:`paired_bootstrap_ci` (of the mean of
per-clip differences between two methods on the same clips), :data:`BOOTSTRAP_RESAMPLES` = 10 000
resamples, seed 0, 95 %, from :data:`MIN_CLIPS_FOR_INTERVAL` clips on ("too few clips for an interval"
below it).

Run time (benchmarks/evaluation_cost.py on synthetic clips, 2-core CPU; CPU seconds of the process,
the machine was shared so wall times were ~2.5x these): a 49-frame 720x480 clip costs PSNR 0.9 s,
SSIM 8.1 s, Warp-SSIM 11.6 s (DIS flows of the target 5.5 s, reusable across methods, + scoring
6.0 s), T-CLIP with a ViT-B/32-size CLIP 13.7 s; a 17-frame 128x96 clip PSNR 0.002 s, SSIM 0.08 s,
Warp-SSIM 0.19 s, T-CLIP 4.0 s (the CLIP input is always 224 px). LPIPS (AlexNet): measured with the
``lpips`` 0.1.4 package in a throwaway environment at 19.9 s and 0.47 s of CPU for the two clips, before
:mod:`lightcrafter.lpips_net` replaced it (not re-measured).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

PSNR_CAP_DB = 100.0
#: skimage's SSIM needs frames at least this many pixels on each side (its 7-px default window)
SSIM_MIN_SIDE_PX = 7

#: scikit-image SSIM settings (Wang et al. 2004): Gaussian 11-tap window, sigma 1.5, population covariance.
SSIM_SETTINGS = dict(gaussian_weights=True, sigma=1.5, use_sample_covariance=False, K1=0.01, K2=0.03, data_range=1.0)
#: Half-width (px) of the SSIM window, int(3.5 * sigma + 0.5): the border excluded from SSIM means.
SSIM_BORDER_PX = int(3.5 * SSIM_SETTINGS["sigma"] + 0.5)

#: OpenCV DIS optical flow preset used for Warp-SSIM (MEDIUM: ~0.01 px mean error on a textured
#: 720x480 translation, ~70 ms per flow on this machine; FAST/ULTRAFAST err ~0.06 px).
FLOW_PRESET = "MEDIUM"
#: Forward-backward consistency thresholds (Sundaram, Brox & Keutzer, ECCV 2010).
OCCLUSION_ALPHA = 0.01
OCCLUSION_BETA = 0.5
#: Motion-boundary test of the same paper: |grad u|^2 + |grad v|^2 > 0.01 |w|^2 + 0.002 is unreliable.
MOTION_BOUNDARY_ALPHA = 0.01
MOTION_BOUNDARY_BETA = 0.002

BOOTSTRAP_RESAMPLES = 10_000
BOOTSTRAP_SEED = 0
BOOTSTRAP_CONFIDENCE = 0.95
#: fewest clips an interval is computed from; below it results say "too few clips for an interval". A
#: nominal 95 % percentile bootstrap of a mean of normal values covers the true mean in 76 % of samples of 3,
#: 84 % of 5, 89 % of 6 to 10 and 92 % of 12 (1000 simulated samples each, 2000 resamples): from 6 on it is
#: near its large-sample behaviour.
MIN_CLIPS_FOR_INTERVAL = 6



# ----------------------------------------------------------------------------- result type
@dataclass(frozen=True)
class MetricResult:
    """One metric on one clip.

    ``value`` is the clip score (None when not computed), ``per_item`` the per-frame values (PSNR,
    SSIM, LPIPS) or per-transition values (Warp-SSIM, T-CLIP), ``status`` "computed" or
    "not computed: <reason>", ``info`` the settings used (library, preset, thresholds, weights).
    """

    name: str
    value: float | None
    per_item: tuple[float, ...] = ()
    status: str = "computed"
    info: dict = field(default_factory=dict)

    @property
    def computed(self) -> bool:
        return self.value is not None

    def to_dict(self) -> dict:
        """JSON-ready: non-finite per-item values (a transition with no kept pixel) become None."""
        return {"name": self.name, "value": self.value, "status": self.status,
                "per_item": [float(x) if np.isfinite(x) else None for x in self.per_item], "info": dict(self.info)}

    @staticmethod
    def not_computed(name: str, reason: str, **info) -> "MetricResult":
        return MetricResult(name, None, (), f"not computed: {reason}", dict(info))


def _finite_mean(values: Sequence[float]) -> float | None:
    v = np.asarray(values, np.float64)
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else None


# ----------------------------------------------------------------------------- input checks
def _as_display_video(video, name: str) -> np.ndarray:
    """The video as a float array (float32 stays float32: no whole-video copy), checked to be
    (N, H, W, 3) with finite values in [0, 1] (tolerance 1e-6)."""
    v = np.asarray(video)
    if v.ndim != 4 or v.shape[-1] != 3:
        raise ValueError(f"{name}: expected a display video shaped (N, H, W, 3), got {v.shape}")
    if not np.issubdtype(v.dtype, np.floating):
        raise ValueError(f"{name}: expected float display values in [0, 1], got dtype {v.dtype}")
    if v.size and (not np.isfinite(v).all() or v.min() < -1e-6 or v.max() > 1 + 1e-6):
        raise ValueError(f"{name}: display values must be finite and in [0, 1]; "
                         "convert linear frames with lightcrafter.io.linear_to_display")
    return v


def _pair(method, target) -> tuple[np.ndarray, np.ndarray]:
    m, t = _as_display_video(method, "method video"), _as_display_video(target, "target video")
    if m.shape != t.shape:
        raise ValueError(f"method video {m.shape} and target video {t.shape} differ in shape")
    return m, t


# ----------------------------------------------------------------------------- PSNR / SSIM
def psnr_db(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR in dB (peak 1) of two display images of equal shape; +inf when identical."""
    from skimage.metrics import peak_signal_noise_ratio

    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a.shape != b.shape:
        raise ValueError(f"psnr: shapes differ {a.shape} vs {b.shape}")
    with np.errstate(divide="ignore"):  # identical images: MSE 0 -> +inf
        return float(peak_signal_noise_ratio(a, b, data_range=1.0))


def ssim(a: np.ndarray, b: np.ndarray) -> float:
    """SSIM (:data:`SSIM_SETTINGS`) of two (H, W, C) or (H, W) display images in [0, 1]."""
    from skimage.metrics import structural_similarity

    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a.shape != b.shape:
        raise ValueError(f"ssim: shapes differ {a.shape} vs {b.shape}")
    return float(structural_similarity(a, b, channel_axis=-1 if a.ndim == 3 else None, **SSIM_SETTINGS))


def ssim_map(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(H, W) SSIM map (:data:`SSIM_SETTINGS`, full=True) averaged over channels; its border of
    :data:`SSIM_BORDER_PX` px is what :func:`ssim` leaves out of its mean."""
    from skimage.metrics import structural_similarity

    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a.shape != b.shape:
        raise ValueError(f"ssim: shapes differ {a.shape} vs {b.shape}")
    _, s = structural_similarity(a, b, channel_axis=-1 if a.ndim == 3 else None, full=True, **SSIM_SETTINGS)
    return s.mean(axis=-1) if a.ndim == 3 else s


def framewise_psnr(method, target) -> MetricResult:
    """Per-frame PSNR (dB, each capped at :data:`PSNR_CAP_DB`) and their mean."""
    m, t = _pair(method, target)
    vals = tuple(min(psnr_db(x, y), PSNR_CAP_DB) for x, y in zip(m, t))
    return MetricResult("psnr_db", _finite_mean(vals), vals,
                        info={"library": "skimage.metrics.peak_signal_noise_ratio", "data_range": 1.0,
                              "cap_db": PSNR_CAP_DB, "values": "display [0, 1]"})


def framewise_ssim(method, target) -> MetricResult:
    """Per-frame SSIM (:data:`SSIM_SETTINGS`) and their mean; not computed for frames smaller than the
    window (:data:`SSIM_MIN_SIDE_PX`)."""
    m, t = _pair(method, target)
    if min(m.shape[1:3]) < SSIM_MIN_SIDE_PX:
        return MetricResult.not_computed("ssim", f"frames {m.shape[2]}x{m.shape[1]} are smaller than SSIM's "
                                         f"{SSIM_MIN_SIDE_PX}-px window")
    vals = tuple(ssim(x, y) for x, y in zip(m, t))
    return MetricResult("ssim", _finite_mean(vals), vals,
                        info={"library": "skimage.metrics.structural_similarity", **SSIM_SETTINGS,
                              "values": "display [0, 1]"})


def video_psnr_db(a: np.ndarray, b: np.ndarray) -> float:
    """Mean over frames of per-frame PSNR (dB), each capped at :data:`PSNR_CAP_DB`."""
    return float(np.mean([min(psnr_db(x, y), PSNR_CAP_DB) for x, y in zip(a, b)]))


def video_ssim(a: np.ndarray, b: np.ndarray) -> float:
    """Mean over frames of per-frame SSIM."""
    return float(np.mean([ssim(x, y) for x, y in zip(a, b)]))


def display_psnr_db(linear: np.ndarray, linear_ref: np.ndarray, exposure_ev: float = 0.0) -> float:
    """PSNR (dB, peak 1) of two LINEAR images after the shared display transform (io.linear_to_display)."""
    from .io import linear_to_display

    return psnr_db(linear_to_display(linear, exposure_ev), linear_to_display(linear_ref, exposure_ev))


def temporal_difference(video: np.ndarray) -> np.ndarray:
    """(N-1,) mean |frame[i+1] - frame[i]| for a (N, H, W, C) video."""
    v = np.asarray(video, np.float64)
    return np.abs(np.diff(v, axis=0)).reshape(len(v) - 1, -1).mean(axis=1)


# ----------------------------------------------------------------------------- coding artifacts
#: latent frame 0 of CogVideoX's autoencoder (and the tiny preset's) is pixel frame 0 and latent frame k >= 1
#: holds pixel frames 4k-3..4k: transitions 0 -> 1, 4 -> 5, 8 -> 9, ... cross a temporal block boundary
LATENT_FRAMES_PER_BLOCK = 4


def blockiness(video, period: int = 8) -> MetricResult:
    """Block-grid texture (no reference): mean |horizontal or vertical neighbour difference| of luma across
    the grid lines every ``period`` pixels (between pixel ``period*k - 1`` and ``period*k``) over the same
    mean elsewhere. 1 = no grid (natural images scatter around 1); a patch autoencoder's 8x8 blocks raise it
    at period 8 and 16. Per frame, then the mean; not computed for frames narrower than 2 periods or with no
    gradient at all (a constant frame)."""
    v = _as_display_video(video, "video")
    n, h, w, _ = v.shape
    if min(h, w) < 2 * period:
        return MetricResult.not_computed(f"blockiness_{period}", f"frames {w}x{h} are smaller than 2 periods "
                                         f"of {period} px")
    luma = v @ np.array([0.2126, 0.7152, 0.0722])
    dx, dy = np.abs(np.diff(luma, axis=2)), np.abs(np.diff(luma, axis=1))  # (n, h, w-1), (n, h-1, w)
    on_x = (np.arange(w - 1) + 1) % period == 0
    on_y = (np.arange(h - 1) + 1) % period == 0
    vals = []
    for i in range(n):
        grid = np.concatenate([dx[i][:, on_x].ravel(), dy[i][on_y].ravel()])
        rest = np.concatenate([dx[i][:, ~on_x].ravel(), dy[i][~on_y].ravel()])
        vals.append(float(grid.mean() / rest.mean()) if rest.mean() > 1e-9 else float("nan"))
    value = _finite_mean(vals)
    if value is None:
        return MetricResult.not_computed(f"blockiness_{period}", "no gradient in any frame (constant frames)")
    return MetricResult(f"blockiness_{period}", value, tuple(vals), info={"period_px": period, "input": "luma"})


def block_jump(video, block: int = LATENT_FRAMES_PER_BLOCK) -> MetricResult:
    """Temporal jumps at the autoencoder's frame blocks (no reference): mean |frame t+1 - frame t| over the
    transitions that cross a block boundary (t = 0, 4, 8, ...: frame 0 alone is latent frame 0 and pixel
    frame 4k the last of latent frame k) over the same mean elsewhere. 1 = no jump at block boundaries. Not computed for clips with no boundary
    transition and another, or without motion at all (zero flow, identical frames)."""
    v = _as_display_video(video, "video")
    if len(v) < block + 2:
        return MetricResult.not_computed(f"jump_{block}", f"{len(v)} frames: no block boundary with a "
                                         "transition on either side")
    d = temporal_difference(v)  # d[t] = |frame t+1 - frame t|
    t = np.arange(len(d))
    at = t % block == 0
    other = ~at
    if d[other].mean() <= 1e-9:
        return MetricResult.not_computed(f"jump_{block}", "the frames do not change between boundaries")
    return MetricResult(f"jump_{block}", float(d[at].mean() / d[other].mean()), tuple(float(x) for x in d),
                        info={"frames_per_block": block, "boundary_transitions": [int(x) for x in t[at]]})


# ----------------------------------------------------------------------------- optical flow
#: OpenCV's DIS needs a frame side of at least this many pixels
DIS_MIN_SIDE_PX = 12


def no_flow_reason(video) -> str | None:
    """Why a display video has no flow (None when it has one)."""
    v = np.asarray(video)
    if len(v) < 2:
        return "a one-frame clip has no motion"
    if max(v.shape[1:3]) < DIS_MIN_SIDE_PX:
        return f"frames {v.shape[2]}x{v.shape[1]} are smaller than the {DIS_MIN_SIDE_PX} px OpenCV's DIS flow needs"
    return None


def _luma_u8(frame: np.ndarray) -> np.ndarray:
    import cv2

    g = cv2.cvtColor(np.asarray(frame, np.float32), cv2.COLOR_RGB2GRAY)
    return np.clip(np.round(g * 255.0), 0, 255).astype(np.uint8)


def _dis(preset: str):
    import cv2

    try:
        code = getattr(cv2, f"DISOPTICAL_FLOW_PRESET_{preset.upper()}")
    except AttributeError:
        raise ValueError(f"unknown DIS preset {preset!r}; use ULTRAFAST, FAST or MEDIUM") from None
    return cv2.DISOpticalFlow_create(code)


def dis_flow(frame_a: np.ndarray, frame_b: np.ndarray, preset: str = FLOW_PRESET) -> np.ndarray:
    """(H, W, 2) float32 flow (dx, dy) in pixels from display frame a to b: a(x) ~ b(x + flow(x))."""
    return _dis(preset).calc(_luma_u8(frame_a), _luma_u8(frame_b), None)


def warp_backward(image: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """Sample ``image`` at x + flow(x) (cv2.remap, bilinear, border replicated): brings frame t+1
    back onto frame t with the forward flow t -> t+1."""
    import cv2

    h, w = flow.shape[:2]
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    return cv2.remap(np.asarray(image, np.float32), gx + flow[..., 0], gy + flow[..., 1],
                     interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def consistency_mask(fwd: np.ndarray, bwd: np.ndarray, alpha: float = OCCLUSION_ALPHA,
                     beta: float = OCCLUSION_BETA, boundary_alpha: float = MOTION_BOUNDARY_ALPHA,
                     boundary_beta: float = MOTION_BOUNDARY_BETA) -> np.ndarray:
    """(H, W) bool: pixels of frame t with a reliable match in t+1 (Sundaram et al. 2010):

    * x + f(x) inside the image;
    * forward-backward consistent: |f + b(x+f)|^2 < alpha (|f|^2 + |b(x+f)|^2) + beta;
    * not on a motion boundary: |grad f_x|^2 + |grad f_y|^2 <= boundary_alpha |f|^2 + boundary_beta
      (a local flow such as DIS smears a moving object's motion a few pixels onto the background it
      covers, where forward and backward flows then agree; this test removes that band).
    """
    b_at = warp_backward(bwd, fwd)
    err = np.sum((fwd + b_at) ** 2, axis=-1)
    mag = np.sum(fwd**2, axis=-1)
    consistent = err < alpha * (mag + np.sum(b_at**2, axis=-1)) + beta
    gy_u, gx_u = np.gradient(fwd[..., 0])
    gy_v, gx_v = np.gradient(fwd[..., 1])
    smooth = gx_u**2 + gy_u**2 + gx_v**2 + gy_v**2 <= boundary_alpha * mag + boundary_beta
    return _inside(fwd) & consistent & smooth


def _inside(fwd: np.ndarray) -> np.ndarray:
    """(H, W) bool: x + fwd(x) lies inside the image (pixel centres at integer coordinates)."""
    h, w = fwd.shape[:2]
    gx, gy = np.meshgrid(np.arange(w), np.arange(h))
    tx, ty = gx + fwd[..., 0], gy + fwd[..., 1]
    return (tx >= 0) & (tx <= w - 1) & (ty >= 0) & (ty <= h - 1)


@dataclass(frozen=True)
class VideoFlows:
    """Forward flows and consistency masks of one reference video, reusable across methods.

    ``forward[t]``: (H, W, 2) flow t -> t+1; ``valid[t]``: (H, W) bool mask of :func:`consistency_mask`.
    """

    forward: tuple[np.ndarray, ...]
    valid: tuple[np.ndarray, ...]
    preset: str
    alpha: float
    beta: float

    @property
    def shape(self) -> tuple[int, int]:
        return self.forward[0].shape[:2] if self.forward else (0, 0)


def compute_flows(video, preset: str = FLOW_PRESET, alpha: float = OCCLUSION_ALPHA,
                  beta: float = OCCLUSION_BETA) -> VideoFlows:
    """DIS forward/backward flow between adjacent frames of a display video and occlusion masks; a
    ValueError (one line) for frames OpenCV's DIS cannot take (:func:`no_flow_reason`)."""
    v = _as_display_video(video, "flow reference video")
    why = no_flow_reason(v)
    if why:
        raise ValueError(f"optical flow: {why}")
    dis = _dis(preset)
    luma = [_luma_u8(f) for f in v]
    fwd, valid = [], []
    for t in range(len(v) - 1):
        f = dis.calc(luma[t], luma[t + 1], None)
        b = dis.calc(luma[t + 1], luma[t], None)
        fwd.append(f)
        valid.append(consistency_mask(f, b, alpha, beta))
    return VideoFlows(tuple(fwd), tuple(valid), preset, alpha, beta)


def warp_ssim(method, reference=None, flows: VideoFlows | None = None, mask_occlusions: bool = True,
              flow_source: str = "target") -> MetricResult:
    """Warp-SSIM of ``method`` with flow from ``reference`` (or precomputed ``flows`` of it).

    Per transition t: SSIM map between method[t] and method[t+1] warped back by the reference's
    forward flow, averaged over unoccluded pixels (``mask_occlusions=False`` averages over all
    pixels inside the image, for diagnosis only). ``per_item`` is the per-transition curve;
    ``info['valid_fraction']`` the kept fraction of the interior per transition.
    """
    m = _as_display_video(method, "method video")
    if len(m) < 2:
        return MetricResult.not_computed("warp_ssim", f"needs at least 2 frames, got {len(m)}")
    if flows is None:
        if reference is None:
            raise ValueError("warp_ssim: give the reference video (target or original input) or its flows")
        r = _as_display_video(reference, "flow reference video")
        if r.shape != m.shape:
            raise ValueError(f"method video {m.shape} and flow reference video {r.shape} differ in shape")
        flows = compute_flows(r)
    if len(flows.forward) != len(m) - 1 or flows.shape != m.shape[1:3]:
        raise ValueError(f"flows cover {len(flows.forward)} transitions of {flows.shape}, "
                         f"method video has {len(m) - 1} of {m.shape[1:3]}")
    h, w = m.shape[1:3]
    interior = np.zeros((h, w), bool)
    p = SSIM_BORDER_PX
    interior[p:h - p, p:w - p] = True
    curve, frac = [], []
    for t in range(len(m) - 1):
        warped = warp_backward(m[t + 1], flows.forward[t])
        s = ssim_map(warped, m[t])
        keep = interior & (flows.valid[t] if mask_occlusions else _inside(flows.forward[t]))
        n = int(keep.sum())
        frac.append(n / max(int(interior.sum()), 1))
        curve.append(float(s[keep].mean()) if n else float("nan"))
    value = _finite_mean(curve)
    info = {"flow": f"cv2 DIS preset {flows.preset}", "flow_source": flow_source, "alpha": flows.alpha,
            "beta": flows.beta, "motion_boundary": [MOTION_BOUNDARY_ALPHA, MOTION_BOUNDARY_BETA],
            "occlusions_masked": mask_occlusions, "warp": "cv2.remap bilinear",
            "ssim": SSIM_SETTINGS, "valid_fraction": [round(f, 6) for f in frac]}
    if value is None:
        return MetricResult.not_computed("warp_ssim", "no unoccluded pixel in any transition", **info)
    return MetricResult("warp_ssim", value, tuple(curve), info=info)


# ----------------------------------------------------------------------------- T-CLIP
class ClipImageEmbedder:
    """CLIP image embeddings from a local ``transformers`` CLIP folder (nothing is downloaded)."""

    def __init__(self, model, processor, source: str, batch_size: int = 16):
        self.model, self.processor, self.source, self.batch_size = model.eval(), processor, source, batch_size

    @classmethod
    def from_folder(cls, folder: str | Path, batch_size: int = 16) -> "ClipImageEmbedder":
        """Load ``CLIPModel`` and ``CLIPImageProcessorPil`` with local_files_only; raises
        :class:`lightcrafter.io.DataError` naming the folder when it exists but cannot be loaded."""
        from transformers import CLIPImageProcessorPil, CLIPModel

        from .io import DataError

        folder = Path(folder)
        if not (folder / "preprocessor_config.json").is_file():
            raise DataError(f"{folder}: no preprocessor_config.json; save the CLIP folder with its image "
                            "processor (CLIPProcessor.save_pretrained) next to the model")
        try:
            model = CLIPModel.from_pretrained(folder, local_files_only=True)
            proc = CLIPImageProcessorPil.from_pretrained(folder, local_files_only=True)
        except (OSError, ValueError) as exc:
            raise DataError(f"{folder}: not a loadable transformers CLIP folder ({exc}); "
                            "point evaluation.clip_weights at a CLIPModel.save_pretrained folder") from exc
        return cls(model, proc, str(folder), batch_size)

    def embed(self, video) -> np.ndarray:
        """(N, D) float64 unit-norm image embeddings of a display video (frames sent as 8-bit)."""
        import torch

        from .io import to_uint8

        frames = to_uint8(_as_display_video(video, "video"))
        out = []
        with torch.no_grad():
            for i in range(0, len(frames), self.batch_size):
                px = self.processor(images=list(frames[i:i + self.batch_size]), return_tensors="pt")["pixel_values"]
                pooled = self.model.vision_model(pixel_values=px).pooler_output
                out.append(self.model.visual_projection(pooled).double().numpy())
        e = np.concatenate(out, axis=0)
        return e / np.linalg.norm(e, axis=1, keepdims=True)


@functools.lru_cache(maxsize=2)
def _cached_embedder(folder: str) -> ClipImageEmbedder:
    return ClipImageEmbedder.from_folder(folder)


def load_clip_embedder(clip_weights: str | Path | None) -> ClipImageEmbedder | str:
    """An embedder for ``clip_weights``, or the "not computed" reason string when there is none."""
    if not clip_weights:
        return "no CLIP weights configured (evaluation.clip_weights is empty); nothing is downloaded"
    folder = Path(clip_weights)
    if not folder.is_dir():
        return f"no CLIP weights at {folder}"
    try:
        import transformers  # noqa: F401
    except ImportError as exc:
        return f"transformers cannot be imported ({exc}); pip install transformers==5.23.0"
    return _cached_embedder(str(folder.resolve()))


def t_clip(video, clip_weights: str | Path | None = None, embedder: ClipImageEmbedder | None = None,
           pairs: str = "adjacent") -> MetricResult:
    """T-CLIP: mean cosine similarity of CLIP image embeddings of adjacent frames.

    ``per_item`` holds the per-transition similarities; ``pairs="all"`` averages over all frame
    pairs instead (the curve stays the adjacent one).
    """
    if pairs not in ("adjacent", "all"):
        raise ValueError(f"t_clip: pairs must be 'adjacent' or 'all', got {pairs!r}")
    v = _as_display_video(video, "video")
    if embedder is None:
        loaded = load_clip_embedder(clip_weights)
        if isinstance(loaded, str):
            return MetricResult.not_computed("t_clip", loaded, clip_weights=str(clip_weights or ""))
        embedder = loaded
    if len(v) < 2:
        return MetricResult.not_computed("t_clip", f"needs at least 2 frames, got {len(v)}")
    e = embedder.embed(v)
    adjacent = tuple(float(x) for x in np.sum(e[:-1] * e[1:], axis=1))
    if pairs == "adjacent":
        value = float(np.mean(adjacent))
    else:
        g = e @ e.T
        n = len(e)
        value = float((g.sum() - np.trace(g)) / (n * (n - 1)))
    return MetricResult("t_clip", value, adjacent,
                        info={"clip_weights": embedder.source, "pairs": pairs,
                              "library": "transformers CLIPModel + CLIPImageProcessorPil", "input": "display -> uint8"})


# ----------------------------------------------------------------------------- LPIPS
def load_lpips(lpips_weights: str | Path | None, net: str = "alex"):
    """The LPIPS v0.1 module (:mod:`lightcrafter.lpips_net`, plain torch) from the local folder
    ``lpips_weights``, or the "not computed" reason string.

    The folder holds torchvision's backbone checkpoint (:data:`lightcrafter.lpips_net.BACKBONE_FILES`, e.g.
    ``alexnet-owt-7be5be79.pth``) and the v0.1 linear layers (``alex.pth``, from the ``lpips`` package's
    ``weights/v0.1/``), directly or under ``checkpoints/``. A file that is there but wrong is a one-line
    :class:`DataError` naming it.
    """
    from lightcrafter import lpips_net

    if net not in lpips_net.BACKBONE_FILES:
        raise ValueError(f"lpips: net must be one of {sorted(lpips_net.BACKBONE_FILES)}, got {net!r}")
    if not lpips_weights:
        return "no LPIPS weights configured (evaluation.lpips_weights is empty); nothing is downloaded"
    folder = Path(lpips_weights)
    if not folder.is_dir():
        return f"no LPIPS weights at {folder}"
    found = {}
    for what, name in (("backbone", lpips_net.BACKBONE_FILES[net]), ("linear", lpips_net.LINEAR_FILES[net])):
        found[what] = lpips_net.find_file(folder, name)
        if found[what] is None:
            return f"no LPIPS weights at {folder}: {name} is missing there (directly or under checkpoints/)"
    return lpips_net.build(str(found["backbone"].resolve()), str(found["linear"].resolve()), net)


def lpips_video(method, target, lpips_weights: str | Path | None = None, net: str = "alex",
                model=None, batch_size: int = 8) -> MetricResult:
    """Per-frame LPIPS (``lpips`` v0.1, inputs scaled to [-1, 1]) and the mean over frames.

    Not computed (value None) without the local weight files (:func:`load_lpips`).
    """
    m, t = _pair(method, target)
    if model is None:
        loaded = load_lpips(lpips_weights, net)
        if isinstance(loaded, str):
            return MetricResult.not_computed("lpips", loaded, lpips_weights=str(lpips_weights or ""), net=net)
        model = loaded
    import torch

    from lightcrafter.lpips_net import MIN_SIDE

    if min(m.shape[1:3]) < MIN_SIDE.get(net, 0):
        return MetricResult.not_computed("lpips", f"frames {m.shape[2]}x{m.shape[1]} are smaller than the {MIN_SIDE[net]} "
                                         f"px the {net} backbone needs on each side", net=net)

    def to_t(x):
        return torch.from_numpy(np.ascontiguousarray(x.transpose(0, 3, 1, 2), dtype=np.float32)) * 2.0 - 1.0

    vals = []
    with torch.no_grad():
        for i in range(0, len(m), batch_size):
            d = model(to_t(m[i:i + batch_size]), to_t(t[i:i + batch_size]))
            vals.extend(float(x) for x in d.reshape(-1))
    return MetricResult("lpips", _finite_mean(vals), tuple(vals),
                        info={"library": "lightcrafter.lpips_net (LPIPS v0.1)", "net": net, "input": "display scaled to [-1, 1]",
                              "lpips_weights": str(lpips_weights or "")})


# ----------------------------------------------------------------------------- the metric registry
@dataclass
class Context:
    """What the metrics of one clip share: the target (display), its flows (None for one frame), and the
    loaded networks or the reason each is not available (strings)."""

    target: np.ndarray
    flows: VideoFlows | None = None
    lpips: object = "LPIPS not loaded"
    clip: object = "CLIP not loaded"

    @staticmethod
    def of(target, lpips=None, clip=None) -> "Context":
        """The context of ``target``: its flows where it has them; ``lpips`` / ``clip`` the loaded networks
        (or their reasons, :func:`load_lpips` / :func:`load_clip_embedder`)."""
        t = _as_display_video(target, "target video")
        return Context(t, None if no_flow_reason(t) else compute_flows(t),
                       lpips if lpips is not None else load_lpips(None),
                       clip if clip is not None else load_clip_embedder(None))


@dataclass(frozen=True)
class Metric:
    """One metric: ``name`` (results key), ``label`` (tables), ``higher_is_better`` (None: judged against the
    target's own value, e.g. coding artifacts, which the report shows apart from the tables), ``needs_reference``
    (False: also measured on the target), ``compute(video, ctx) -> MetricResult`` and ``temporal`` (it compares
    frames with each other: no column for a one-frame benchmark)."""

    name: str
    label: str
    higher_is_better: bool | None
    needs_reference: bool
    compute: Callable[[np.ndarray, Context], MetricResult]
    temporal: bool = False


def _needs(what, name):
    return MetricResult.not_computed(name, what)


METRICS: dict[str, Metric] = {m.name: m for m in (
    Metric("psnr_db", "PSNR", True, True, lambda v, c: framewise_psnr(v, c.target)),
    Metric("ssim", "SSIM", True, True, lambda v, c: framewise_ssim(v, c.target)),
    Metric("lpips", "LPIPS", False, True, lambda v, c: _needs(c.lpips, "lpips") if isinstance(c.lpips, str)
           else lpips_video(v, c.target, model=c.lpips)),
    Metric("t_clip", "T-CLIP", True, False, lambda v, c: _needs(c.clip, "t_clip") if isinstance(c.clip, str)
           else t_clip(v, embedder=c.clip), temporal=True),
    Metric("warp_ssim", "Warp-SSIM", True, True, lambda v, c: warp_ssim(v, flows=c.flows) if c.flows is not None
           else _needs(no_flow_reason(c.target), "warp_ssim"), temporal=True),
    Metric("blockiness_8", "blockiness 8 px", None, False, lambda v, c: blockiness(v, 8)),
    Metric("blockiness_16", "blockiness 16 px", None, False, lambda v, c: blockiness(v, 16)),
    Metric("jump_4", "4-frame jump", None, False, lambda v, c: block_jump(v, LATENT_FRAMES_PER_BLOCK), temporal=True),
)}


def evaluate_video(video, ctx: Context, names: Sequence[str] | None = None) -> dict[str, MetricResult]:
    """Every registered metric (or ``names``) of one display video against ``ctx.target``."""
    v = _as_display_video(video, "method video")
    if v.shape != ctx.target.shape:
        raise ValueError(f"method video {v.shape} and target video {ctx.target.shape} differ in shape")
    return {n: METRICS[n].compute(v, ctx) for n in (names or METRICS)}


def evaluate_target(ctx: Context) -> dict[str, MetricResult]:
    """The no-reference metrics of the target itself (what a method's artifacts are judged against)."""
    return {n: m.compute(ctx.target, ctx) for n, m in METRICS.items() if not m.needs_reference}


# ----------------------------------------------------------------------------- aggregation
def bootstrap_ci(values: Sequence[float], n_resamples: int = BOOTSTRAP_RESAMPLES,
                 confidence: float = BOOTSTRAP_CONFIDENCE, seed: int = BOOTSTRAP_SEED) -> dict:
    """Percentile bootstrap CI of the mean of per-clip values (clips resampled with replacement): the one
    interval of the project and its one shape, {"mean", "low", "high", "n", "n_resamples", "confidence",
    "seed", "method", "too_few"}.

    Below :data:`MIN_CLIPS_FOR_INTERVAL` values ``low`` and ``high`` are None and ``too_few`` says so (a
    percentile bootstrap over 3 values is only their range, and no verdict may rest on it). Empty or
    non-finite input is a ValueError."""
    v = np.asarray(values, np.float64)
    if v.ndim != 1 or v.size < 1 or not np.isfinite(v).all():
        raise ValueError(f"bootstrap_ci: need finite per-clip values, got {v.shape} "
                         f"({int((~np.isfinite(v)).sum()) if v.size else 0} non-finite)")
    out = {"mean": float(v.mean()), "low": None, "high": None, "n": int(v.size), "n_resamples": int(n_resamples),
           "confidence": float(confidence), "seed": int(seed), "method": "percentile bootstrap over clips",
           "too_few": None}
    if v.size < MIN_CLIPS_FOR_INTERVAL:
        out["too_few"] = f"too few clips for an interval ({v.size} < {MIN_CLIPS_FOR_INTERVAL})"
        return out
    rng = np.random.default_rng(seed)
    means = v[rng.integers(0, v.size, size=(n_resamples, v.size))].mean(axis=1)
    lo, hi = np.quantile(means, [(1 - confidence) / 2, (1 + confidence) / 2])
    out.update(low=float(lo), high=float(hi))
    return out


def paired_bootstrap_ci(a: Sequence[float], b: Sequence[float], n_resamples: int = BOOTSTRAP_RESAMPLES,
                        confidence: float = BOOTSTRAP_CONFIDENCE, seed: int = BOOTSTRAP_SEED) -> dict:
    """Percentile bootstrap CI of mean(a - b) over the same clips (pairs resampled together); the shape of
    :func:`bootstrap_ci`."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a.shape != b.shape:
        raise ValueError(f"paired_bootstrap_ci: {a.shape} vs {b.shape} values; pair the same clips")
    out = bootstrap_ci(a - b, n_resamples, confidence, seed)
    out["method"] = "paired percentile bootstrap over clips (a - b)"
    return out
