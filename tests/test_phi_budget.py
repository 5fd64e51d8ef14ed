"""Phi's error budget (benchmarks/phi_budget.py): one component swapped at a time, nothing else."""

from __future__ import annotations

import importlib.util
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from lightcrafter import io
from lightcrafter.clip import FrameView
from lightcrafter.recon.evaluate import ground_pixels

spec = importlib.util.spec_from_file_location("phi_budget", Path(__file__).resolve().parents[1] / "benchmarks" /
                                              "phi_budget.py")
budget = importlib.util.module_from_spec(spec)
spec.loader.exec_module(budget)

H, W = 6, 8


def _view(seed: int, hole: slice) -> FrameView:
    rng = np.random.default_rng(seed)
    mask = np.ones((H, W), np.float32)
    mask[hole] = 0
    n = rng.normal(size=(H, W, 3)).astype(np.float32)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    b = io.Buffers(depth=np.where(mask > 0, rng.uniform(1, 5, (H, W)), np.inf).astype(np.float32),
                   normal=np.where(mask[..., None] > 0, n, 0).astype(np.float32),
                   albedo=rng.random((H, W, 3)).astype(np.float32), roughness=rng.random((H, W)).astype(np.float32),
                   metallic=rng.random((H, W)).astype(np.float32), mask=mask)
    return FrameView(b, np.eye(3) * (seed + 1), np.eye(4) * (seed + 2), f"v{seed}")


FIELDS = {"depth": ["depth"], "normals": ["normal"], "albedo": ["albedo"], "roughness_metallic": ["roughness", "metallic"]}


@pytest.mark.parametrize("component", list(FIELDS))
def test_a_buffer_component_comes_from_the_donor_where_both_are_surface_and_nothing_else_changes(component):
    base, donor = _view(0, np.s_[0, :]), _view(1, np.s_[:, 0])
    out = budget.swap(base, donor, component)
    both = (base.buffers.mask > 0) & (donor.buffers.mask > 0)
    for k in ("depth", "normal", "albedo", "roughness", "metallic", "mask"):
        got, b, d = getattr(out.buffers, k), getattr(base.buffers, k), getattr(donor.buffers, k)
        if k in FIELDS[component]:
            np.testing.assert_array_equal(got[both], d[both])
            np.testing.assert_array_equal(got[~both], b[~both])
        else:
            np.testing.assert_array_equal(got, b)
    assert out.K is base.K and out.c2w is base.c2w


def test_mask_swap_takes_the_donors_surface_pixels_and_drops_the_ones_it_lacks():
    base, donor = _view(0, np.s_[0, :]), _view(1, np.s_[:, 0])
    out = budget.swap(base, donor, "mask").buffers
    np.testing.assert_array_equal(out.mask > 0, donor.buffers.mask > 0)
    assert np.isinf(out.depth[:, 0]).all()  # the donor's hole
    np.testing.assert_array_equal(out.albedo[0, 1:], donor.buffers.albedo[0, 1:])  # only the donor sees row 0
    np.testing.assert_array_equal(out.albedo[1:, 1:], base.buffers.albedo[1:, 1:])


def test_ground_normals_come_from_the_donor_on_the_ground_truths_ground_only():
    gt, phi = _view(0, np.s_[0, :]), _view(1, np.s_[:, 0])
    up = gt.buffers.normal.copy()
    up[3:] = [0.0, 0.0, 1.0]  # rows 3.. are ground
    up[3, 2] = [np.sin(np.radians(5.0)), 0.0, np.cos(np.radians(5.0))]  # tilted 5 degrees: not ground
    gt = FrameView(replace(gt.buffers, normal=up), gt.K, gt.c2w, gt.key)
    ground = ground_pixels(gt.buffers)
    assert ground[4:, :].all() and not ground[:3].any() and not ground[3, 2] and ground[3, 3]
    both = (gt.buffers.mask > 0) & (phi.buffers.mask > 0)
    fixed = budget.swap(phi, gt, "ground_normals", ground).buffers  # phi+gt: Phi's ground turned to the truth
    np.testing.assert_array_equal(fixed.normal[ground & both], up[ground & both])
    np.testing.assert_array_equal(fixed.normal[~(ground & both)], phi.buffers.normal[~(ground & both)])
    for k in ("depth", "albedo", "roughness", "metallic", "mask"):
        np.testing.assert_array_equal(getattr(fixed, k), getattr(phi.buffers, k))
    with pytest.raises(ValueError, match="ground pixels"):
        budget.swap(phi, gt, "ground_normals")


def test_camera_swap_and_identity():
    base, donor = _view(0, np.s_[0, :]), _view(1, np.s_[:, 0])
    cam = budget.swap(base, donor, "cameras")
    assert cam.buffers is base.buffers and cam.K is donor.K and cam.c2w is donor.c2w
    for c in budget.COMPONENTS:
        same = budget.swap(base, base, c, np.ones((H, W), bool)).buffers
        for k in ("depth", "normal", "albedo", "roughness", "metallic", "mask"):
            np.testing.assert_array_equal(getattr(same, k), getattr(base.buffers, k))
    with pytest.raises(ValueError, match="component"):
        budget.swap(base, donor, "lighting")


def test_budget_rows_name_every_component_both_ways_and_take_phis_ground_normals_only_on_the_true_ground():
    from lightcrafter.config import effective_config
    from lightcrafter.proxy import render_settings

    gt, phi = _view(0, np.s_[0, :]), _view(1, np.s_[:, 0])
    up = gt.buffers.normal.copy()
    up[3:] = [0.0, 0.0, 1.0]
    gt = FrameView(replace(gt.buffers, normal=up), gt.K, gt.c2w, gt.key)
    rows = {name: views for name, _, views in budget.budget_rows([gt], [phi], render_settings(
        effective_config(None)["proxy"]), True)}
    assert {"oracle", "phi"} | {f"{d}:{c}" for c in budget.COMPONENTS for d in ("gt+phi", "phi+gt")} <= set(rows)
    ground = ground_pixels(gt.buffers) & (phi.buffers.mask > 0)
    np.testing.assert_array_equal(rows["gt+phi:ground_normals"][0].buffers.normal[ground], phi.buffers.normal[ground])
    np.testing.assert_array_equal(rows["gt+phi:ground_normals"][0].buffers.normal[~ground], up[~ground])
    np.testing.assert_array_equal(rows["phi+gt:ground_normals"][0].buffers.normal[ground], up[ground])


def test_albedo_colour_rows_move_only_the_clips_albedo_colour():
    """gt+phi:albedo_colour: the true albedo in Phi's colour (its least-squares gain undone); phi+gt:albedo_colour:
    Phi's albedo in the true colour; nothing else changes."""
    from lightcrafter.config import effective_config
    from lightcrafter.proxy import render_settings

    gt = _view(0, np.s_[0, :])
    tint = np.array([0.5, 1.0, 1.5], np.float32)
    phi = FrameView(replace(gt.buffers, albedo=gt.buffers.albedo * tint), gt.K, gt.c2w, "phi")
    rows = {name: views for name, _, views in budget.budget_rows([gt], [phi], render_settings(
        effective_config(None)["proxy"]), True)}
    surf = gt.buffers.mask > 0
    expect = np.clip(gt.buffers.albedo * tint, 0, 1)
    np.testing.assert_allclose(rows["gt+phi:albedo_colour"][0].buffers.albedo[surf], expect[surf], rtol=1e-5)
    np.testing.assert_allclose(rows["phi+gt:albedo_colour"][0].buffers.albedo[surf], gt.buffers.albedo[surf],
                               rtol=1e-5, atol=1e-6)
    for k in ("depth", "normal", "roughness", "metallic", "mask"):
        np.testing.assert_array_equal(getattr(rows["gt+phi:albedo_colour"][0].buffers, k), getattr(gt.buffers, k))


@pytest.mark.slow
def test_the_budget_of_a_run_measures_rs_own_sampling_noise_and_the_report_shows_it(e2e_run, tmp_path):
    """benchmarks/phi_budget.py on the tiny run's test pairs with R's own rows: the oracle against 16x its samples
    (its sampling noise), the denoised oracle, and the report's budget section listing them."""
    import json
    import subprocess
    import sys

    from lightcrafter.report.sections import _budget_section

    repo = Path(__file__).resolve().parents[1]
    out = tmp_path / "bench" / "phi_budget.json"
    r = subprocess.run([sys.executable, str(repo / "benchmarks" / "phi_budget.py"), "--results",
                        str(e2e_run / "results"), "--config", str(repo / "config" / "ci.yaml"), "--rows",
                        "oracle,oracle@16x,phi", "--out", str(out)], capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    res = json.loads(out.read_text())
    table = res["table"]
    assert res["pairs"] >= 1 and set(table) == {"oracle", "oracle+oidn", "oracle@16x", "oracle_vs_16x", "phi"}
    for name, row in table.items():
        if name == "oracle+oidn" and "not_computed" in row:  # no pyoidn: said so, not scored
            continue
        assert np.isfinite(row["psnr_db"]) and 0 < row["ssim"] <= 1, name
    # R's sampling noise is far below its gap to the Cycles target
    assert table["oracle_vs_16x"]["psnr_db"] > table["oracle"]["psnr_db"]
    assert len(list((out.parent / "phi_budget_strips").glob("*.png"))) == res["pairs"]
    html = _budget_section(tmp_path)
    assert all(f"<td>{name}</td>" in html for name in ("oracle", "oracle@16x", "oracle_vs_16x", "phi"))
