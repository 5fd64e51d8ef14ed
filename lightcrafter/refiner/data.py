"""Pairs dataset: reads ``pairs.jsonl`` (docs/architecture.md) into display-space tensors.

Each record's ``proxy`` and ``target`` are folders of linear EXR frames ``{frame:04d}.exr``
(frames 0 .. num_frames-1). Frames go through the one display transform
(:func:`lightcrafter.io.linear_to_display`, same exposure for proxy and target) and are mapped to
[-1, 1]. Relative paths are resolved against ``root`` (default: the working directory, i.e. the
workflow root), falling back to the manifest's folder.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import torch

from lightcrafter.io import DataError, linear_to_display, read_jsonl, read_rgb_exr

REQUIRED = ("pair_id", "proxy", "target", "num_frames", "width", "height", "split")


def read_pairs(pairs_path: str | Path, split: str | None = None) -> list[dict]:
    records = read_jsonl(pairs_path)
    for i, r in enumerate(records, 1):
        missing = [k for k in REQUIRED if k not in r]
        if missing:
            raise DataError(f"{pairs_path}:{i}: pair record lacks {missing}; rebuild the dataset manifest")
    return [r for r in records if split is None or r["split"] == split]


def require_pairs(dataset, pairs_path, split: str | None, task: str):
    """``dataset`` itself when it has a pair, else a one-line :class:`DataError` naming the manifest and the split:
    a benchmark of zero clips has no mean, so ``task`` (e.g. "refine") stops instead of writing an empty result."""
    if len(dataset) == 0:
        counts = Counter(r.get("split") for r in read_jsonl(pairs_path))
        has = ", ".join(f"{k}: {v}" for k, v in sorted(counts.items(), key=str)) or "no pairs at all"
        raise DataError(f"{pairs_path}: no pairs with split == {split!r} to {task} (the manifest has {has}); pass "
                        "the split it has, or rebuild it with clips in that split")
    return dataset


def _resolve(p: str, root: Path, manifest_dir: Path) -> Path:
    p = Path(p)
    if p.is_absolute():
        return p
    return root / p if (root / p).exists() or not (manifest_dir / p).exists() else manifest_dir / p


def load_frames(folder: Path, num_frames: int, exposure_ev: float = 0.0) -> torch.Tensor:
    """Folder of linear EXR frames -> (3, N, H, W) float32 display values in [-1, 1]."""
    if not folder.is_dir():
        raise DataError(f"{folder}: frame folder not found; run the stage that renders it")
    frames = [linear_to_display(read_rgb_exr(folder / f"{i:04d}.exr"), exposure_ev) for i in range(num_frames)]
    arr = np.stack(frames).transpose(3, 0, 1, 2)  # (3, N, H, W)
    return torch.from_numpy(arr * 2.0 - 1.0).float()


def to_display_frames(video: torch.Tensor) -> np.ndarray:
    """Inverse layout of :func:`load_frames`: (3, N, H, W) in [-1, 1] -> (N, H, W, 3) display in [0, 1]."""
    return ((video.detach().cpu().float() + 1) / 2).clamp(0, 1).permute(1, 2, 3, 0).numpy()


class PairsDataset:
    """Index-able list of pairs of one split; ``ds[i]`` -> {pair_id, proxy, target} (3, N, H, W) in [-1, 1]."""

    def __init__(self, pairs_path, split: str | None, exposure_ev: float = 0.0, root=None, limit=None,
                 cache: bool = True, pair_ids=None):
        """``pair_ids``: keep only these pairs (in manifest order), e.g. a validation carve-out."""
        self.pairs_path = Path(pairs_path)
        self.records = read_pairs(pairs_path, split)
        if pair_ids is not None:
            keep = set(pair_ids)
            self.records = [r for r in self.records if r["pair_id"] in keep]
        if limit is not None:
            self.records = self.records[: int(limit)]
        self.exposure_ev = exposure_ev
        self.root = Path(root) if root is not None else Path.cwd()
        self.cache = cache
        self._cache: dict[int, dict] = {}

    def __len__(self) -> int:
        return len(self.records)

    @property
    def pair_ids(self) -> list[str]:
        return [r["pair_id"] for r in self.records]

    def data_identity(self) -> list:
        """What the pairs' frames are, without reading them: each record and, per proxy/target
        folder, its manifest text (``{folder}.json``, rewritten whenever the frames are) or else
        the frames' names, sizes and modification times. Used to decide whether a checkpoint
        belongs to this data."""
        md = self.pairs_path.parent
        out = []
        for r in self.records:
            item = [r]
            for key in ("proxy", "target"):
                folder = _resolve(r[key], self.root, md)
                manifest = folder.with_suffix(".json")
                if manifest.is_file():
                    item.append(manifest.read_text())
                else:
                    item.append(sorted((f.name, f.stat().st_size, f.stat().st_mtime_ns) for f in folder.glob("*.exr")))
            out.append(item)
        return out

    def __getitem__(self, i: int) -> dict:
        if i in self._cache:
            return self._cache[i]
        r = self.records[i]
        md = self.pairs_path.parent
        n = int(r["num_frames"])
        item = {
            "pair_id": r["pair_id"],
            "proxy": load_frames(_resolve(r["proxy"], self.root, md), n, self.exposure_ev),
            "target": load_frames(_resolve(r["target"], self.root, md), n, self.exposure_ev),
        }
        for k in ("proxy", "target"):
            if tuple(item[k].shape[2:]) != (int(r["height"]), int(r["width"])):
                raise DataError(f"{self.pairs_path}: pair {r['pair_id']} {k} frames are "
                                f"{tuple(item[k].shape[2:])}, record says {r['height']}x{r['width']}")
        if self.cache:
            self._cache[i] = item
        return item

    def source_frames(self, i: int) -> torch.Tensor | None:
        """(3, N, H, W) in [-1, 1] of the record's optional ``source`` (the input video under the
        source light, a folder of linear EXR frames), or None when the record has none."""
        r = self.records[i]
        if not r.get("source"):
            return None
        return load_frames(_resolve(r["source"], self.root, self.pairs_path.parent), int(r["num_frames"]),
                           self.exposure_ev)
