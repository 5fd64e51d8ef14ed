"""Scene edits: light insertion, material edits in a world region, object insertion with occlusion."""

import numpy as np
import pytest

from lightcrafter import editing, io
from lightcrafter.clip import FrameView
from lightcrafter.proxy import synthetic as syn
from lightcrafter.proxy.lighting import Lighting

W, H = 64, 48


def _view(cam=(0.0, -4.0, 1.2)):
    K = syn.intrinsics(W, H, 0.9)
    c2w = syn.look_at(list(cam), [0, 0, 0.5])
    b = syn.raycast_buffers(K, c2w, W, H, [syn.Sphere((0, 0, 0.5), 0.5, albedo=(0.2, 0.6, 0.2))])
    return FrameView(b, K, c2w, "v")


def _glb(tmp_path, size=0.4):
    from lightcrafter.blender.testing import write_textured_glb

    return write_textured_glb(tmp_path / "box.glb", size_m=size)


def test_inserted_object_is_occluded_by_nearer_surfaces(tmp_path):
    v = _view()
    glb = _glb(tmp_path)
    (front,), f_front = editing.insert_object([v], glb, [0.0, -1.2, 0.0])  # between camera and sphere
    (behind,), f_behind = editing.insert_object([v], glb, [0.0, 1.0, 0.0])  # hidden behind the sphere
    assert f_front > 0.02
    sphere = (v.buffers.mask > 0) & (v.buffers.depth < 4.5)
    changed_front = front.buffers.depth < v.buffers.depth - 1e-4
    changed_behind = behind.buffers.depth != v.buffers.depth
    assert changed_front.sum() > 0 and not (changed_behind & sphere).any()
    # the box's own material: the GLB's sRGB texel decoded to linear, roughness/metallic factors
    from lightcrafter.blender import testing

    lin = testing.srgb8_to_linear(testing.GLB_TEXTURE_SRGB8)
    np.testing.assert_allclose(front.buffers.albedo[changed_front].mean(0), lin, atol=0.02)
    assert np.allclose(front.buffers.roughness[changed_front], testing.GLB_ROUGHNESS)
    # normals stay unit and face the camera
    n = front.buffers.normal[changed_front]
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-4)


def test_material_edit_stays_in_its_world_region():
    v = _view()
    (edited,), frac = editing.material_edit_views([v], [0, 0, 0.5], 0.6, {"albedo_override": [0.9, 0.1, 0.1],
                                                                             "metallic_override": 1.0})
    inside = editing.region_mask(v, [0, 0, 0.5], 0.6) > 0
    assert 0.05 < frac < 0.9
    np.testing.assert_allclose(edited.buffers.albedo[inside], [[0.9, 0.1, 0.1]] * int(inside.sum()), atol=1e-6)
    np.testing.assert_array_equal(edited.buffers.albedo[~inside], v.buffers.albedo[~inside])
    assert np.all(edited.buffers.metallic[inside] == 1.0) and np.all(edited.buffers.depth == v.buffers.depth)


def test_light_insertion_adds_to_the_lighting():
    base = Lighting(env=np.ones((4, 8, 3), np.float32))
    lit = editing.insert_lights(base, [{"position_m": [0, 0, 2], "intensity_w_sr": [5, 5, 5]}],
                                [{"center_m": [1, 0, 2], "normal": [0, 0, -1], "size_m": [0.5, 0.5], "radiance": [2, 2, 2]}])
    assert len(lit.point_lights) == 1 and len(lit.area_lights) == 1 and lit.env is base.env
    assert not base.point_lights  # the original lighting is untouched


def test_free_ground_spot_avoids_objects():
    spec = {"objects": [{"location_m": [0.7, 0.0, 0], "footprint_radius_m": 0.4},
                        {"location_m": [-0.7, 0.0, 0], "footprint_radius_m": 0.4}]}
    p = editing.free_ground_spot(spec)
    assert p[2] == 0 and min(np.linalg.norm(p[:2] - np.array(o["location_m"][:2])) for o in spec["objects"]) > 0.8


def test_corrupt_glb_is_one_line_error(tmp_path):
    bad = tmp_path / "bad.glb"
    bad.write_bytes(b"glTF\x02\x00\x00\x00garbage")
    with pytest.raises(io.DataError, match="bad.glb"):
        editing.load_glb(bad)
