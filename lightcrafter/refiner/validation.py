"""Validation carve-out: whole scenes of the train split held out for model selection.

Never touches the test split. A pair's *group* is its ``scene_id`` (synthetic pairs), else its
``clip_id`` (real pseudo-pairs), else its ``pair_id``: every clip of a scene lands on the same side,
so validation scores measure generalisation to unseen scenes as the test split does.

The held-out groups are the first ``n`` train-split groups ordered by sha256("{seed}:{group}"):
deterministic in the seed, independent of the manifest's order, and stable when scenes are added
(a group's rank among the others never changes).
"""

from __future__ import annotations

import hashlib


def pair_group(record: dict) -> str:
    return str(record.get("scene_id") or record.get("clip_id") or record["pair_id"])


def num_val_groups(val_scenes: float, num_groups: int) -> int:
    """``val_scenes``: a count (integer >= 1), a fraction in (0, 1) (rounded, at least 1), or 0.

    Returns 0 when fewer than 2 groups exist (nothing would be left to train on)."""
    v = float(val_scenes)
    if v <= 0 or num_groups < 2:
        return 0
    n = int(v) if v >= 1 else max(1, int(round(v * num_groups)))
    return min(n, num_groups - 1)


def carve_validation(records: list[dict], val_scenes: float, seed: int = 0) -> dict:
    """Split train-split ``records`` into fit and validation pairs by whole group.

    Returns {"fit": [pair_id], "val": [pair_id], "val_groups": [group], "fit_groups": [group],
    "note": str}; pairs keep manifest order. Records of another split raise ValueError.
    """
    bad = [r["pair_id"] for r in records if r.get("split") != "train"]
    if bad:
        raise ValueError(f"validation is carved from the train split only; got other splits for {bad[:3]}")
    groups = sorted({pair_group(r) for r in records})
    n = num_val_groups(val_scenes, len(groups))
    ranked = sorted(groups, key=lambda g: hashlib.sha256(f"{seed}:{g}".encode()).hexdigest())
    val_groups = sorted(ranked[:n])
    fit = [r["pair_id"] for r in records if pair_group(r) not in val_groups]
    val = [r["pair_id"] for r in records if pair_group(r) in val_groups]
    if float(val_scenes) > 0 and n == 0:
        note = f"selection skipped: {len(groups)} train-split scene(s), validation needs at least 2"
    else:
        note = f"{n} of {len(groups)} train-split scenes held out for validation"
    return {"fit": fit, "val": val, "val_groups": val_groups,
            "fit_groups": [g for g in groups if g not in val_groups], "note": note}
