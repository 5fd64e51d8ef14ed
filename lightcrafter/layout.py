"""Where every product of the pipeline lives: one path builder per product, used by the rules, the
dataset builders, the benchmarks and the report (as PyPSA-Eur's ``resources()`` helpers do).

Every function takes the output root (``results`` by default, config ``output_dir``) and ids; passing
Snakemake wildcard placeholders (``"{scene}"``) gives the rule patterns. Folders of frames have a
manifest ``<folder>.json`` written last (see lightcrafter.clip and docs/architecture.md).
"""

from __future__ import annotations

from pathlib import Path


class Layout:
    """Result paths under ``root`` (strings, relative to the workflow's working directory)."""

    def __init__(self, root: str = "results"):
        self.root = str(root).rstrip("/")

    def _p(self, *parts) -> str:
        return "/".join([self.root, *map(str, parts)])

    # assets and scenes
    def assets_manifest(self) -> str:
        return self._p("assets", "manifest.json")

    def scene_spec(self, scene) -> str:
        return self._p("scenes", scene, "scene.json")

    def split_trajectories(self, split: str) -> list[tuple[dict, dict]]:
        """(scene spec, trajectory) of every trajectory of the written scene specs of ``split``, in scene-id
        order (for the benchmarks that read a finished run)."""
        from lightcrafter.io import read_json

        out = []
        for spec_file in sorted(Path(self.root, "scenes").glob("*/scene.json")):
            spec = read_json(spec_file)
            if spec.get("split") == split:
                out += [(spec, t) for t in spec["trajectories"]]
        return out

    # ground truth (Blender): a clip per trajectory, radiance per lighting
    def gt_clip(self, scene, traj) -> str:
        return self._p("gt", scene, traj)

    def gt_clip_manifest(self, scene, traj) -> str:
        return self._p("gt", scene, traj, "buffers.json")

    def gt_rgb(self, scene, traj, light) -> str:
        """Folder of linear frames; ``<folder>.json`` manifest, ``<folder>.mp4`` preview."""
        return self._p("gt", scene, traj, "rgb", light)

    def summary(self, name) -> str:
        return self._p("summary", f"{name}.json")

    # reconstruction stack
    def estimator(self) -> str:
        return self._p("recon", "estimator", "model.pt")

    def estimator_curve(self) -> str:
        return self._p("recon", "estimator", "curve.json")

    def recon_clip(self, kind, clip) -> str:
        """Phi's clip of a synthetic trajectory (kind 'synthetic', clip '{scene}_{traj}') or a real clip."""
        return self._p("recon", kind, clip)

    def recon_clip_manifest(self, kind, clip) -> str:
        return self._p("recon", kind, clip, "buffers.json")

    def aligned_clip(self, scene, traj) -> str:
        return self._p("aligned", scene, traj)

    def aligned_clip_manifest(self, scene, traj) -> str:
        return self._p("aligned", scene, traj, "buffers.json")

    # proxies rendered by R
    def proxy_gt(self, scene, traj, light) -> str:
        """Oracle proxy: R on ground-truth buffers."""
        return self._p("proxy_gt", scene, traj, light)

    def proxy(self, scene, traj, light) -> str:
        """Artifact-matched proxy: R on Align(Phi(source video))."""
        return self._p("proxy", scene, traj, light)

    # real videos
    def real_frames(self, clip) -> str:
        return self._p("real", clip, "rgb")

    def envfit(self, clip) -> str:
        return self._p("envfit", clip)

    def envfit_lighting(self, clip) -> str:
        """The fitted source lighting of a real clip (lightcrafter.lighting/1 file)."""
        return self._p("envfit", clip, "lighting.json")

    def envfit_manifest(self, clip) -> str:
        return self._p("envfit", clip, "fit.json")

    def pseudo_input(self, clip) -> str:
        """R(S, L_hat_source) of a real clip (written by the envmap fit): the proxy of a real pseudo-pair."""
        return self._p("envfit", clip, "pseudo")

    # long-form check and scene edits
    def longform_spec(self) -> str:
        return self._p("longform", "scene.json")

    def longform_clip_manifest(self, traj) -> str:
        return self._p("longform", "gt", traj, "buffers.json")

    def longform_rgb(self, traj, light) -> str:
        return self._p("longform", "gt", traj, "rgb", light)

    def longform_proxy(self, light) -> str:
        return self._p("longform", "proxy", light)

    def longform_metrics(self) -> str:
        return self._p("longform", "metrics.json")

    def edit_record(self, kind) -> str:
        return self._p("edits", kind, "edit.json")

    def edit_clip_manifest(self, kind) -> str:
        return self._p("edits", kind, "clip", "buffers.json")

    def edit_lighting(self, kind) -> str:
        return self._p("edits", kind, "lighting.json")

    def edit_proxy(self, kind) -> str:
        return self._p("edits", kind, "proxy")

    def edit_refined(self, kind) -> str:
        return self._p("edits", kind, "refined")

    # datasets, refiner, evaluation, report
    def pairs(self, variant) -> str:
        return self._p("datasets", variant, "pairs.jsonl")

    def benchmark_pairs(self, bench) -> str:
        return self._p("benchmarks", bench, "pairs.jsonl")

    def refiner_dir(self, variant) -> str:
        return self._p("refiner", variant)

    def empty_prompt(self) -> str:
        return self._p("refiner", "empty_prompt.pt")

    def refiner_model(self, variant) -> str:
        return self._p("refiner", variant, "model.pt")

    def refined(self, variant, bench) -> str:
        return self._p("refined", variant, bench)

    def refined_manifest(self, variant, bench) -> str:
        return self._p("refined", variant, bench, "manifest.json")

    def eval_metrics(self, variant, bench) -> str:
        return self._p("eval", variant, bench, "metrics.json")

    def report_index(self) -> str:
        return self._p("report", "index.html")


def root_of(path: str | Path, product: str) -> Path:
    """The output root from a path produced by :class:`Layout` (e.g. root_of('results/datasets/x/pairs.jsonl',
    'datasets') -> 'results'): the parent of the first component named ``product``."""
    p = Path(path)
    parts = p.parts
    if product not in parts:
        raise ValueError(f"{path}: no '{product}' component; not a pipeline output path")
    return Path(*parts[: parts.index(product)]) if parts.index(product) else Path(".")
