"""Build a bpy (Cycles) scene from a ``lightcrafter.scene/1`` spec (docs/architecture.md).

One scene per process: :func:`build_scene` starts from Blender's empty factory settings, so
nothing from a previous build survives, and everything it creates is reachable from the
returned :class:`BuiltScene` (no module-level state).

Conventions
-----------
* World: Blender's, right-handed, Z up, metres; the ground plane is z = 0.
* Objects: ``location_m`` is the centre of the object's base (on z = 0); ``rotation_euler_rad`` is
  Blender's XYZ Euler in radians; ``scale`` is uniform. Primitives are built so that their
  axis-aligned bounding box (before rotation) spans ``dimensions_m`` with its bottom at z = 0.
  Curated GLBs are already normalised (base centre at the origin after glTF's Y-up -> Z-up import).
* Camera: pinhole, horizontal field of view ``camera.fov_x_rad``, sensor fit horizontal, square
  pixels, looking from ``cam_location_m`` at ``cam_target_m`` with world +Z as "up".
  :func:`opencv_c2w` gives the OpenCV camera-to-world matrix; Blender's camera matrix is
  ``c2w_opencv @ diag(1, -1, -1, 1)`` (the flip is its own inverse).
* Intrinsics (:func:`intrinsics`): OpenCV pixel convention, pixel (row i, col j) has its centre at
  (u, v) = (j, i), so the principal point is ((W - 1) / 2, (H - 1) / 2) and
  ``fx = fy = (W / 2) / tan(fov_x_rad / 2)``.
* Environment light: lat-long HDRI through Cycles' Environment Texture, rotated about world Z by
  ``rotation_z_rad`` (+ the frame's ``light_rotation_z_rad``): a feature that the unrotated map
  shows in world direction d appears in direction Rz(angle) d (counter-clockwise seen from above).
* Environment importance map: fixed at :data:`WORLD_MAP_RESOLUTION` (not Cycles' automatic size).
* Output: Cycles on the CPU, fixed seed, optional OIDN denoiser, no adaptive sampling, view transform
  "Standard" / look "None", float32 multilayer EXR, i.e. linear scene-referred radiance.
* Buffers come from the Depth (planar camera z, metres; checked: 1e10 on background), Normal
  (world space) and three shader AOVs: ``albedo`` (COLOR), ``roughness`` and ``metallic`` (VALUE),
  each fed from whatever drives the Principled BSDF's Base Color / Roughness / Metallic input
  (a texture for glTF imports, else the socket's value).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lightcrafter.camera import intrinsics, opencv_c2w  # noqa: F401  (re-exported for callers)
from lightcrafter.io import DataError
from lightcrafter.lights import resolve_hdri
from lightcrafter.scenes import GROUND_PATTERNS, PRIMITIVE_SHAPES, lighting, trajectory  # noqa: F401

AOV_ALBEDO, AOV_ROUGHNESS, AOV_METALLIC = "albedo", "roughness", "metallic"
#: OIDN networks Cycles offers (``denoising_quality``), slowest and best first
DENOISE_QUALITIES = ("high", "balanced", "fast")
# File-name keys (lower case, matched against the stem) for texture-set ground materials.
TEXTURE_SET_KEYS = {
    # PolyHaven: <name>_diff_1k, _rough_, _nor_gl_; ambientCG: <name>_Color, _Roughness, _NormalGL, _Metalness
    "basecolor": ("basecolor", "base_color", "albedo", "diffuse", "diff", "color", "col"),
    "roughness": ("roughness", "rough"),
    "normal": ("normalgl", "normal_gl", "normal", "nor"),
    "metallic": ("metallic", "metalness", "metal"),
}
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".exr", ".tif", ".tiff")
BLENDER_FROM_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])
# Importance map of the environment light (width; height is half). Cycles' "automatic" size is rebuilt
# on every scene change at ~3-4 s per 96x64 frame on 2 cores; a fixed 1024 (the width of the bundled
# HDRIs: one map texel per HDRI pixel) costs ~0.4 s. 512 saves ~0.2 s but loses ~0.5 dB at 16 spp.
WORLD_MAP_RESOLUTION = 1024


@dataclass
class BuiltScene:
    """Handles to what :func:`build_scene` created.

    roots: spec object id -> the bpy object whose transform places it (base centre at origin).
    base_poses: spec object id -> (location_m, rotation_euler_rad) from the spec.
    camera: the bpy camera object. world_mapping: the Mapping node rotating the HDRI (or None).
    lighting: the spec lighting used for the world (or None for buffers).
    """

    spec: dict
    roots: dict = field(default_factory=dict)
    base_poses: dict = field(default_factory=dict)
    camera: object = None
    world_mapping: object = None
    lighting: dict | None = None


def check_inputs(spec: dict, light_id: str | None = None) -> None:
    """Fail early (before any frame is rendered) on missing files: GLBs, HDRI, texture folder."""
    for obj in spec.get("objects", []):
        if obj.get("kind") == "asset":
            path = Path(obj["path"])
            if not path.is_file():
                raise DataError(
                    f"{path}: asset GLB of object {obj.get('id')!r} not found; run curate_assets or fix the path"
                )
            if path.stat().st_size == 0:
                raise DataError(f"{path}: asset GLB is empty; re-run curate_assets for {obj.get('asset_id')!r}")
        elif obj.get("kind") == "primitive" and obj.get("shape") not in PRIMITIVE_SHAPES:
            raise DataError(
                f"object {obj.get('id')!r}: unknown primitive shape {obj.get('shape')!r}; use one of {PRIMITIVE_SHAPES}"
            )
    mat = spec["ground"]["material"]
    if mat.get("type") == "texture_set":
        _texture_set_files(mat)
    if light_id is not None:
        resolve_hdri(lighting(spec, light_id)["hdri"])


# ----------------------------------------------------------------------------- bpy
def import_bpy(threads: int | None = None):
    """Import ``bpy`` with Blender's thread pool (oneTBB) sized to ``threads`` CPU cores, and return it.

    oneTBB sizes its pool from the process's CPU affinity when Blender starts; ``render.threads``
    limits Cycles' path tracing only. On a 2-core machine a 1-thread render job otherwise keeps an
    idle TBB worker spinning on the second core (about 1.1 million ``sched_yield`` calls and 8-9 s
    of system time per 13-frame job of the default, the frames unchanged): CPU time the job was not
    given, counted against it where a scheduler meters CPU. The affinity is narrowed to ``threads``
    cores for the import only and then restored, so the operating system still schedules the job on
    any core. No effect when ``bpy`` is already imported, ``threads`` is None or not below the
    allowed cores, or the platform has no ``sched_setaffinity``.
    """
    import os
    import sys

    setaffinity = getattr(os, "sched_setaffinity", None)
    allowed = os.sched_getaffinity(0) if setaffinity else set()
    narrow = "bpy" not in sys.modules and bool(threads) and int(threads) < len(allowed)
    if narrow:
        setaffinity(0, set(sorted(allowed)[: int(threads)]))
    try:
        import bpy
    finally:
        if narrow:
            setaffinity(0, allowed)
    return bpy


# ----------------------------------------------------------------------------- scene
def build_scene(spec: dict, light_id: str | None = None) -> BuiltScene:
    """Build the spec's scene from empty factory settings; world lighting only if ``light_id`` is given.

    Render settings (samples, filter, passes, output) are set by :func:`configure_render`.
    """
    import bpy

    check_inputs(spec, light_id)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    built = BuiltScene(spec=spec)
    _add_ground(spec["ground"])
    for obj in spec.get("objects", []):
        if obj["kind"] == "asset":
            root = _import_asset(obj)
        elif obj["kind"] == "primitive":
            root = _add_primitive(obj)
        else:
            raise DataError(f"object {obj.get('id')!r}: unknown kind {obj.get('kind')!r}; use 'asset' or 'primitive'")
        s = float(obj.get("scale", 1.0))
        root.scale = (s, s, s)
        built.roots[obj["id"]] = root
        built.base_poses[obj["id"]] = (obj["location_m"], obj.get("rotation_euler_rad", [0.0, 0.0, 0.0]))
    _add_camera(spec, built)
    if light_id is not None:
        built.lighting = lighting(spec, light_id)
        built.world_mapping = _add_world(built.lighting)
    else:
        world = bpy.data.worlds.new("black")
        world.color = (0.0, 0.0, 0.0)
        bpy.context.scene.world = world
    for mat in bpy.data.materials:
        add_material_aovs(mat)
    return built


def set_frame(built: BuiltScene, frame: dict) -> np.ndarray:
    """Pose camera, moving objects and light rotation for one trajectory frame; return OpenCV c2w."""
    import bpy
    from mathutils import Matrix

    c2w = opencv_c2w(frame["cam_location_m"], frame["cam_target_m"])
    built.camera.matrix_world = Matrix((c2w @ BLENDER_FROM_OPENCV).tolist())
    moving = frame.get("objects") or {}
    for oid, root in built.roots.items():
        loc, rot = built.base_poses[oid]
        pose = moving.get(oid, {})
        root.location = pose.get("location_m", loc)
        root.rotation_euler = pose.get("rotation_euler_rad", rot)
    if built.world_mapping is not None:
        angle = float(built.lighting.get("rotation_z_rad", 0.0)) + float(frame.get("light_rotation_z_rad", 0.0))
        built.world_mapping.inputs["Rotation"].default_value = (0.0, 0.0, angle)
    bpy.context.view_layer.update()
    return c2w


CYCLES_DEVICES = ("auto", "cpu", "cuda", "optix")


def select_device(requested: str = "cpu") -> str:
    """Put Cycles on ``requested`` (auto | cpu | cuda | optix) with every GPU of that kind enabled, as
    BlenderProc and Infinigen do; ``auto`` tries OptiX, then CUDA, then the CPU. Returns the device
    used ("CPU", "CUDA" or "OPTIX"). A GPU kind that was asked for and is not there is a DataError
    naming what the node has: a cluster job sent to the wrong node fails instead of rendering on the CPU."""
    import bpy

    if requested not in CYCLES_DEVICES:
        raise DataError(f"render.device={requested!r}: use one of {list(CYCLES_DEVICES)}")
    sc = bpy.context.scene
    if requested == "cpu":
        sc.cycles.device = "CPU"
        return "CPU"
    prefs = bpy.context.preferences.addons["cycles"].preferences
    found = {}
    for kind in (("OPTIX", "CUDA") if requested == "auto" else (requested.upper(),)):
        try:
            prefs.compute_device_type = kind
        except TypeError:  # this Blender build has no such backend
            found[kind] = []
            continue
        prefs.get_devices()
        gpus = [d for d in prefs.devices if d.type == kind]
        found[kind] = [d.name for d in gpus]
        if gpus:
            for d in prefs.devices:
                d.use = d.type == kind
            sc.cycles.device = "GPU"
            return kind
    if requested == "auto":
        prefs.compute_device_type = "NONE"
        sc.cycles.device = "CPU"
        return "CPU"
    raise DataError(f"render.device={requested!r}: no {requested.upper()} device on this node (found {found}); "
                    "run the job on a GPU node or set render.device: auto or cpu")


def configure_render(
    spec: dict,
    *,
    samples: int,
    max_bounces: int,
    filter_width_px: float,
    film_transparent: bool,
    buffers: bool,
    threads: int | None = None,
    denoiser: str | None = None,
    denoise_quality: str = "high",
    clamp_indirect: float = 0.0,
    device: str = "cpu",
) -> str:
    """Cycles settings shared by buffer and RGB renders (see module docstring); returns the device used
    (:func:`select_device`).

    ``denoiser``: None (raw path tracing) or ``"oidn"`` (Intel Open Image Denoise, bundled with Cycles,
    guided by the albedo and normal passes, accurate prefilter). ``denoise_quality``: OIDN's ``high`` |
    ``balanced`` | ``fast`` network (Cycles' ``denoising_quality``). ``clamp_indirect``: maximum radiance
    of one indirect-light sample (0 = off; Cycles' ``sample_clamp_indirect``), the light-path clamp
    that removes fireflies from rare caustic/glossy paths at the price of a little energy.
    """
    import bpy

    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    used = select_device(device)
    sc.cycles.use_adaptive_sampling = False
    if denoiser not in (None, "none", "oidn"):
        raise DataError(f"render.denoiser={denoiser!r}: use 'none' or 'oidn'")
    if denoise_quality not in DENOISE_QUALITIES:
        raise DataError(f"render.denoise_quality={denoise_quality!r}: use one of {', '.join(DENOISE_QUALITIES)}")
    sc.cycles.use_denoising = denoiser == "oidn"
    if denoiser == "oidn":
        sc.cycles.denoiser = "OPENIMAGEDENOISE"
        sc.cycles.denoising_input_passes = "RGB_ALBEDO_NORMAL"
        sc.cycles.denoising_prefilter = "ACCURATE"
        sc.cycles.denoising_quality = denoise_quality.upper()
    sc.cycles.sample_clamp_direct = 0.0
    sc.cycles.sample_clamp_indirect = float(clamp_indirect)
    sc.cycles.seed = int(spec.get("render", {}).get("seed", 0))
    sc.cycles.use_animated_seed = False
    sc.cycles.max_bounces = int(max_bounces)
    set_sampling(samples, filter_width_px)
    sc.render.film_transparent = film_transparent
    sc.render.use_persistent_data = True
    if threads:
        sc.render.threads_mode, sc.render.threads = "FIXED", int(threads)
    sc.view_settings.view_transform = "Standard"
    sc.view_settings.look = "None"
    sc.view_settings.exposure, sc.view_settings.gamma = 0.0, 1.0
    sc.use_nodes = False
    img = sc.render.image_settings
    img.file_format, img.color_depth, img.exr_codec = "OPEN_EXR_MULTILAYER", "32", "NONE"
    vl = bpy.context.view_layer
    vl.use_pass_z = vl.use_pass_normal = buffers
    if buffers and not vl.aovs:
        for name, kind in ((AOV_ALBEDO, "COLOR"), (AOV_ROUGHNESS, "VALUE"), (AOV_METALLIC, "VALUE")):
            aov = vl.aovs.add()
            aov.name, aov.type = name, kind
    return used


def set_sampling(samples: int, filter_width_px: float) -> None:
    """Samples per pixel and the pixel filter of the next render: a box below 1 px (0.01 px: one ray through
    the pixel centre), else Cycles' Blackman-Harris of that width (pixels). Changing only these between two
    renders of one frame keeps the synced scene (persistent data)."""
    import bpy

    sc = bpy.context.scene
    sc.cycles.samples = int(samples)
    sc.cycles.pixel_filter_type = "BOX" if filter_width_px < 1.0 else "BLACKMAN_HARRIS"
    sc.cycles.filter_width = float(filter_width_px)


# ----------------------------------------------------------------------------- materials
def add_material_aovs(mat) -> None:
    """Wire albedo/roughness/metallic shader AOVs from the inputs of the material's Principled BSDF.

    Each AOV takes the socket that drives the Principled input (e.g. a glTF texture's output) or,
    if the input is unlinked, its default value. Materials without a Principled BSDF get none
    (their pixels read 0 in the AOVs).
    """
    if not mat.use_nodes or mat.node_tree is None:
        return
    nt = mat.node_tree
    bsdf = next((n for n in nt.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled"), None)
    if bsdf is None or any(n.bl_idname == "ShaderNodeOutputAOV" for n in nt.nodes):
        return
    for aov_name, socket_name, out_name in (
        (AOV_ALBEDO, "Base Color", "Color"),
        (AOV_ROUGHNESS, "Roughness", "Value"),
        (AOV_METALLIC, "Metallic", "Value"),
    ):
        src = bsdf.inputs[socket_name]
        node = nt.nodes.new("ShaderNodeOutputAOV")
        node.aov_name = aov_name
        if src.is_linked:
            nt.links.new(src.links[0].from_socket, node.inputs[out_name])
        elif out_name == "Color":
            node.inputs["Color"].default_value = tuple(src.default_value)
        else:
            node.inputs["Value"].default_value = float(src.default_value)


def _principled_material(name: str, base_color, roughness: float, metallic: float):
    import bpy

    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (*[float(c) for c in base_color[:3]], 1.0)
    bsdf.inputs["Roughness"].default_value = float(roughness)
    bsdf.inputs["Metallic"].default_value = float(metallic)
    return mat, bsdf


def _ground_material(spec_mat: dict):
    """Procedural (checker|noise|bricks|voronoi mixing color_a/color_b) or texture-set ground material.

    Procedural: the texture node's Scale input is ``scale`` and its coordinates are object-space metres
    (a checker with scale s has squares 1/s metres wide). Texture set (``dir``): images repeat every
    ``scale_m`` metres (or ``1 / scale`` metres); without a roughness / metallic map the material's
    ``roughness`` (default 0.5) / ``metallic`` (default 0) is used.
    """
    kind = spec_mat.get("type", "procedural")
    mat, bsdf = _principled_material(
        "ground", spec_mat.get("color_a", [0.5] * 3), spec_mat.get("roughness", 0.5), spec_mat.get("metallic", 0.0)
    )
    nt = mat.node_tree
    coord = nt.nodes.new("ShaderNodeTexCoord")
    mapping = nt.nodes.new("ShaderNodeMapping")
    scale = float(spec_mat.get("scale", 1.0))
    nt.links.new(coord.outputs["Object"], mapping.inputs["Vector"])
    if kind == "texture_set":
        if "scale_m" in spec_mat:  # one texture tile spans scale_m metres
            scale = 1.0 / float(spec_mat["scale_m"])
        mapping.inputs["Scale"].default_value = (scale, scale, scale)
        files = _texture_set_files(spec_mat)
        for key, path in files.items():
            tex = nt.nodes.new("ShaderNodeTexImage")
            tex.image = _load_image(path, non_color=key != "basecolor")
            nt.links.new(mapping.outputs["Vector"], tex.inputs["Vector"])
            if key == "basecolor":
                nt.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
            elif key == "normal":
                nmap = nt.nodes.new("ShaderNodeNormalMap")
                nt.links.new(tex.outputs["Color"], nmap.inputs["Color"])
                nt.links.new(nmap.outputs["Normal"], bsdf.inputs["Normal"])
            else:
                nt.links.new(tex.outputs["Color"], bsdf.inputs["Roughness" if key == "roughness" else "Metallic"])
        return mat
    pattern = spec_mat.get("pattern")
    if kind != "procedural" or pattern not in GROUND_PATTERNS:
        raise DataError(
            f"ground.material: type {kind!r} / pattern {pattern!r} unsupported; "
            f"use type 'procedural' with pattern in {GROUND_PATTERNS} or type 'texture_set'"
        )
    node_type, fac_out = {
        "checker": ("ShaderNodeTexChecker", "Fac"),
        "noise": ("ShaderNodeTexNoise", "Fac"),
        "bricks": ("ShaderNodeTexBrick", "Fac"),
        "voronoi": ("ShaderNodeTexVoronoi", "Distance"),
    }[pattern]
    tex = nt.nodes.new(node_type)
    tex.inputs["Scale"].default_value = scale
    nt.links.new(mapping.outputs["Vector"], tex.inputs["Vector"])
    mix = nt.nodes.new("ShaderNodeMix")
    mix.data_type = "RGBA"
    a = next(s for s in mix.inputs if s.name == "A" and s.type == "RGBA")
    b = next(s for s in mix.inputs if s.name == "B" and s.type == "RGBA")
    a.default_value = (*[float(c) for c in spec_mat["color_a"][:3]], 1.0)
    b.default_value = (*[float(c) for c in spec_mat["color_b"][:3]], 1.0)
    nt.links.new(tex.outputs[fac_out], mix.inputs["Factor"])
    out = next(s for s in mix.outputs if s.type == "RGBA")
    nt.links.new(out, bsdf.inputs["Base Color"])
    return mat


def _texture_set_files(spec_mat: dict) -> dict:
    """Find basecolor (required), roughness, normal, metallic images in the texture-set folder by name."""
    folder = Path(spec_mat.get("dir") or spec_mat.get("path") or "")
    if not folder.is_dir():
        raise DataError(f"{folder}: ground texture-set folder not found; fix scenes.ground_textures_dir in config")
    images = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    found = {}
    for key, names in TEXTURE_SET_KEYS.items():
        for name in names:  # most specific name first
            hit = next(
                (p for p in images if name in p.stem.lower().replace("-", "_") and p not in found.values()), None
            )
            if hit is not None:
                found[key] = hit
                break
    if "basecolor" not in found:
        raise DataError(
            f"{folder}: no base-colour image (name containing one of {TEXTURE_SET_KEYS['basecolor']}); add one"
        )
    return found


def _load_image(path: Path, non_color: bool):
    import bpy

    try:
        img = bpy.data.images.load(str(path), check_existing=True)
    except RuntimeError as exc:
        raise DataError(f"{path}: unreadable image ({str(exc).splitlines()[0]}); replace the file") from exc
    if non_color:
        img.colorspace_settings.name = "Non-Color"
    return img


# ----------------------------------------------------------------------------- objects
def _add_ground(ground: dict) -> None:
    import bpy

    size = float(ground["size_m"])
    bpy.ops.mesh.primitive_plane_add(size=size, location=(0.0, 0.0, 0.0))
    plane = bpy.context.active_object
    plane.name = "ground"
    plane.data.materials.append(_ground_material(ground["material"]))


def _add_primitive(obj: dict):
    """A primitive whose bounding box spans ``dimensions_m`` with its base centre at the object origin."""
    import bpy

    shape = obj["shape"]
    add = {
        "cube": lambda: bpy.ops.mesh.primitive_cube_add(size=2.0),
        # an icosphere (2,562 vertices): a UV sphere's poles made two renders of one spec differ in scattered
        # pixels, even on one thread (scene s0003 of the default); structure from motion turned that into 1.4 dB
        "sphere": lambda: bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=4, radius=1.0),
        "cylinder": lambda: bpy.ops.mesh.primitive_cylinder_add(vertices=48, radius=1.0, depth=2.0),
        "cone": lambda: bpy.ops.mesh.primitive_cone_add(vertices=48, radius1=1.0, depth=2.0),
        "torus": lambda: bpy.ops.mesh.primitive_torus_add(major_segments=48, minor_segments=16),
    }[shape]
    add()
    ob = bpy.context.active_object
    ob.name = obj["id"]
    verts = np.empty(len(ob.data.vertices) * 3)
    ob.data.vertices.foreach_get("co", verts)
    verts = verts.reshape(-1, 3)
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    dims = np.asarray(obj["dimensions_m"], float)
    centre = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])
    verts = (verts - centre) / np.maximum(hi - lo, 1e-12) * dims
    ob.data.vertices.foreach_set("co", verts.ravel())
    ob.data.update()
    ob.location = (0.0, 0.0, 0.0)
    if shape != "cube":
        bpy.ops.object.shade_smooth_by_angle(angle=math.radians(40.0))
    m = obj.get("material", {})
    mat, _ = _principled_material(
        f"{obj['id']}_mat", m.get("base_color", [0.8] * 3), m.get("roughness", 0.5), m.get("metallic", 0.0)
    )
    ob.data.materials.append(mat)
    return ob


def _import_asset(obj: dict):
    """Import a curated GLB under an empty (the asset's root; base centre at its origin)."""
    import bpy

    path = Path(obj["path"])
    before = set(bpy.data.objects)
    try:
        result = bpy.ops.import_scene.gltf(filepath=str(path))
    except Exception as exc:  # the importer raises RuntimeError with a multi-line traceback
        raise DataError(f"{path}: cannot import GLB ({_first_line(exc)}); re-run curate_assets or replace it") from exc
    new = [o for o in bpy.data.objects if o not in before]
    if "FINISHED" not in result or not any(o.type == "MESH" for o in new):
        raise DataError(f"{path}: GLB has no mesh; re-run curate_assets or replace it")
    for o in [o for o in new if o.type in ("LIGHT", "CAMERA")]:  # a GLB's own lights/cameras are not part of the scene
        new.remove(o)
        bpy.data.objects.remove(o)
    root = bpy.data.objects.new(obj["id"], None)
    bpy.context.scene.collection.objects.link(root)
    for o in new:
        if o.parent is None:
            o.parent = root
    return root


def _first_line(exc: Exception) -> str:
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    return lines[-1] if lines else type(exc).__name__


# ----------------------------------------------------------------------------- camera, world
def _add_camera(spec: dict, built: BuiltScene) -> None:
    import bpy

    render = bpy.context.scene.render  # the image size is part of the camera model
    render.resolution_x = int(spec["resolution"]["width"])
    render.resolution_y = int(spec["resolution"]["height"])
    render.resolution_percentage = 100
    render.pixel_aspect_x = render.pixel_aspect_y = 1.0
    cam = bpy.data.cameras.new("camera")
    cam.type = "PERSP"
    cam.sensor_fit = "HORIZONTAL"
    cam.angle_x = float(spec["camera"]["fov_x_rad"])
    cam.shift_x = cam.shift_y = 0.0
    cam.clip_start, cam.clip_end = 0.01, 1000.0
    ob = bpy.data.objects.new("camera", cam)
    bpy.context.scene.collection.objects.link(ob)
    bpy.context.scene.camera = ob
    built.camera = ob


def _add_world(light: dict):
    """World = Environment Texture(HDRI) rotated about Z, times ``strength``; returns the Mapping node."""
    import bpy

    path = resolve_hdri(light["hdri"])
    world = bpy.data.worlds.new(f"world_{light['id']}")
    world.use_nodes = True
    world.cycles.sampling_method = "MANUAL"
    world.cycles.sample_map_resolution = WORLD_MAP_RESOLUTION
    nt = world.node_tree
    bg = nt.nodes["Background"]
    bg.inputs["Strength"].default_value = float(light.get("strength", 1.0))
    coord = nt.nodes.new("ShaderNodeTexCoord")
    mapping = nt.nodes.new("ShaderNodeMapping")
    mapping.vector_type = "TEXTURE"  # inverse rotation of the lookup = rotation of the environment
    env = nt.nodes.new("ShaderNodeTexEnvironment")
    env.image = _load_image(path, non_color=False)
    nt.links.new(coord.outputs["Generated"], mapping.inputs["Vector"])
    nt.links.new(mapping.outputs["Vector"], env.inputs["Vector"])
    nt.links.new(env.outputs["Color"], bg.inputs["Color"])
    bpy.context.scene.world = world
    mapping.inputs["Rotation"].default_value = (0.0, 0.0, float(light.get("rotation_z_rad", 0.0)))
    return mapping
