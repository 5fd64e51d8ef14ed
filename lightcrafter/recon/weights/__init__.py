"""The project's pretrained G-buffer estimator (config ``recon.estimator.weights: shipped``).

``gbuffer_estimator.pt`` was trained by the project's own rule (``train_gbuffer_estimator``) on the
synthetic recon-only set of ``config/estimator.yaml`` (other seed, assets and scenes than every run
config's test scenes) and copied here by ``scripts/ship_estimator.py``, which writes
``gbuffer_estimator.json`` beside it: commit, config, data counts, the validation curve (errors against
seconds of training) and the validation errors the weights reproduce (tests/test_shipped_estimator.py).

The file may hold several members (:class:`lightcrafter.recon.estimator.EstimatorEnsemble`: the same set and
schedule under other seeds, ``config/estimator_seed*.yaml``; ``ship_estimator.py --add-member``), whose predictions
Phi averages; the provenance then lists each member's record under ``members`` (:func:`member_records`).
"""

from __future__ import annotations

from pathlib import Path

SHIPPED_WEIGHTS = Path(__file__).resolve().parent / "gbuffer_estimator.pt"
SHIPPED_PROVENANCE = SHIPPED_WEIGHTS.with_suffix(".json")


def weights_path(weights: str, trained: str | Path) -> Path:
    """The weights file config ``recon.estimator.weights`` names: ``train`` -> ``trained`` (the
    train_gbuffer_estimator rule's output), ``shipped`` -> :data:`SHIPPED_WEIGHTS`, else the path itself."""
    if weights == "train":
        return Path(trained)
    if weights == "shipped":
        return SHIPPED_WEIGHTS
    return Path(weights)


def check_set_path() -> Path:
    """Held-out validation frames (display RGB + ground-truth buffers, float16) shipped beside the weights:
    the errors recorded in the provenance file are recomputed on them by the tests."""
    return SHIPPED_WEIGHTS.with_name("gbuffer_estimator_check.npz")


def member_records(provenance: dict) -> list[dict]:
    """Each shipped member's provenance record (commit, config, data, curve, ...): ``members`` of an ensemble's
    provenance file, else the file itself (one network)."""
    return list(provenance["members"]) if "members" in provenance else [provenance]
