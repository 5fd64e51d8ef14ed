"""Validation carve-out: whole scenes of the train split held out for model selection.

Never touches the test split. A pair's *group* is its ``scene_id`` (synthetic pairs), else its source
``video`` (real pseudo-pairs: every clip cut from one video is one group, so no video sits on both sides),
else its ``clip_id``, else its ``pair_id``: every clip of a scene lands on the same side, so validation
scores measure generalisation to unseen scenes as the test split does.

The carve is stratified by kind (``kind``: synthetic or real): ``val_scenes`` groups of each kind are held
out, and a kind with fewer than 2 groups keeps them all for fitting. So a variant with both kinds trains on
both (before, the default's 3 synthetic scenes and 2 real clips of one video held out the 2 real clips, and
the full variant trained on synthetic pairs alone). Only when no kind has 2 groups are all groups ranked
together (a tiny run of one scene and one video).

Within a kind the held-out groups are the first ``n`` groups ordered by sha256("{seed}:{group}"):
deterministic in the seed, independent of the manifest's order, and stable when scenes are added
(a group's rank among the others never changes).
"""

from __future__ import annotations

import hashlib


def pair_group(record: dict) -> str:
    return str(record.get("scene_id") or record.get("video") or record.get("clip_id") or record["pair_id"])


def pair_kind(record: dict) -> str:
    """``kind`` of the record (synthetic | real), else synthetic when it names a scene, else real."""
    return str(record.get("kind") or ("synthetic" if record.get("scene_id") else "real"))


def num_val_groups(val_scenes: float, num_groups: int) -> int:
    """``val_scenes``: a count (integer >= 1), a fraction in (0, 1) (rounded, at least 1), or 0.

    Returns 0 when fewer than 2 groups exist (nothing would be left to train on)."""
    v = float(val_scenes)
    if v <= 0 or num_groups < 2:
        return 0
    n = int(v) if v >= 1 else max(1, int(round(v * num_groups)))
    return min(n, num_groups - 1)


KIND_NOUNS = {"synthetic": "synthetic scene(s)", "real": "real video(s)"}


def _ranked(groups, seed: int) -> list[str]:
    return sorted(groups, key=lambda g: hashlib.sha256(f"{seed}:{g}".encode()).hexdigest())


def carve_validation(records: list[dict], val_scenes: float, seed: int = 0) -> dict:
    """Split train-split ``records`` into fit and validation pairs by whole group, ``val_scenes`` groups of
    each kind (:func:`pair_kind`); when no kind has 2 groups, the groups of all kinds are ranked together
    (a tiny run: one synthetic scene and one real video hold one of the two out).

    Returns {"fit": [pair_id], "val": [pair_id], "val_groups": [group], "fit_groups": [group],
    "note": str}; pairs keep manifest order. Records of another split raise ValueError.
    """
    bad = [r["pair_id"] for r in records if r.get("split") != "train"]
    if bad:
        raise ValueError(f"validation is carved from the train split only; got other splits for {bad[:3]}")
    by_kind: dict[str, set[str]] = {}
    for r in records:
        by_kind.setdefault(pair_kind(r), set()).add(pair_group(r))
    kinds = {k: sorted(by_kind[k]) for k in sorted(by_kind, key=lambda k: (k != "synthetic", k))}
    all_groups = sorted(g for gs in kinds.values() for g in gs)
    counts = ", ".join(f"{len(g)} {KIND_NOUNS.get(k, k)}" for k, g in kinds.items())
    if any(len(g) >= 2 for g in kinds.values()):
        val_groups, parts = [], []
        for kind, groups in kinds.items():
            n = num_val_groups(val_scenes, len(groups))
            val_groups += _ranked(groups, seed)[:n]
            parts.append(f"{n} of {len(groups)} {KIND_NOUNS.get(kind, kind)}")
        note = f"held out for validation: {', '.join(parts)} (by kind; a kind needs 2 to hold one out)"
    else:
        n = num_val_groups(val_scenes, len(all_groups))
        val_groups = _ranked(all_groups, seed)[:n]
        note = f"{n} of {len(all_groups)} train-split scenes held out for validation ({counts}; no kind has 2)"
    if float(val_scenes) > 0 and not val_groups:
        note = f"selection skipped: {counts} in the train split; validation needs at least 2 scenes"
    val_groups = sorted(val_groups)
    fit = [r["pair_id"] for r in records if pair_group(r) not in val_groups]
    val = [r["pair_id"] for r in records if pair_group(r) in val_groups]
    return {"fit": fit, "val": val, "val_groups": val_groups,
            "fit_groups": [g for g in all_groups if g not in val_groups], "note": note}
