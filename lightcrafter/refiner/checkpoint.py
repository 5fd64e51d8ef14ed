"""What a local CogVideoX-I2V diffusers folder can serve, read from its JSON files (no torch import).

The folder layout is the released one: ``model_index.json`` and ``transformer/``, ``vae/``,
``text_encoder/``, ``tokenizer/``, ``scheduler/``. The refiner needs

* ``transformer.in_channels == 2 * vae.latent_channels`` (noisy latent || proxy latent; 5B-I2V: 32 = 2 x 16);
* with learned positional embeddings (5B-I2V has them besides RoPE), every window the transformer sees
  must be exactly the size they were learned for: ``sample_height x sample_width`` latents
  (x 8 pixels: 480 x 720 for 5B-I2V) and ``(sample_frames - 1) / 4 + 1`` latent frames (13 = 49 pixel
  frames). diffusers raises on another size but *silently* swaps in sin-cos embeddings for another
  frame count, so both are checked when the config is read: ``scenes.width/height`` must be the
  learned size and ``refiner.train.latent_window`` and ``refiner.infer.window`` the learned length.
  Clips shorter than the window (one-frame MIT inputs, short real clips) are repeated to the window
  (the last frame), refined, and cropped back (:func:`lightcrafter.refiner.frames.pad_to_latent_frames`);
* a T5 tokenizer that loads: ``tokenizer/spiece.model`` needs the ``sentencepiece`` and ``protobuf``
  packages (requirements.txt, envs/refiner.yaml).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from ..errors import DataError

SUBFOLDERS = ("transformer", "vae", "text_encoder", "tokenizer", "scheduler")
VAE_SPATIAL = 8
VAE_TEMPORAL = 4


class CheckpointError(DataError):
    """A model folder the refiner cannot use (one line naming the file and the fix); a DataError, so that every
    entry point reports it in one line (scripts/_cli.py)."""


@dataclass(frozen=True)
class Servable:
    """What the checkpoint's transformer serves. ``None`` fields: any size (RoPE / sin-cos only)."""

    in_channels: int
    latent_channels: int
    height_px: int | None
    width_px: int | None
    window_latent: int | None

    @property
    def window_frames(self) -> int | None:
        return None if self.window_latent is None else VAE_TEMPORAL * (self.window_latent - 1) + 1


def _json(path: Path) -> dict:
    if not path.is_file():
        raise CheckpointError(f"{path}: not found; the model folder must be a diffusers CogVideoX-I2V folder "
                              f"({'/, '.join(SUBFOLDERS)}/ and model_index.json)")
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise CheckpointError(f"{path}: not readable JSON ({exc}); re-copy the model folder") from exc


def read_servable(root) -> Servable:
    """Read and check the folder's layout and channel counts (module docstring)."""
    root = Path(root)
    missing = [d for d in SUBFOLDERS if not (root / d).is_dir()]
    if missing:
        raise CheckpointError(f"{root}: lacks {', '.join(d + '/' for d in missing)}; the model folder must be a "
                              f"diffusers CogVideoX-I2V folder ({'/, '.join(SUBFOLDERS)}/ and model_index.json)")
    _json(root / "model_index.json")
    tc = _json(root / "transformer" / "config.json")
    vc = _json(root / "vae" / "config.json")
    lat = int(vc.get("latent_channels", 16))
    cin = int(tc.get("in_channels", 16))
    if cin != 2 * lat:
        raise CheckpointError(
            f"{root / 'transformer' / 'config.json'}: in_channels={cin}, but the refiner concatenates the noisy and "
            f"the proxy latent ({lat} + {lat} = {2 * lat}); use an I2V checkpoint (CogVideoX-5B-I2V has 32)")
    learned = bool(tc.get("use_learned_positional_embeddings", False))
    if learned and not tc.get("use_rotary_positional_embeddings", False):
        raise CheckpointError(f"{root / 'transformer' / 'config.json'}: learned positional embeddings without "
                              "rotary ones are not supported by diffusers; use the released config")
    if not learned:
        return Servable(cin, lat, None, None, None)
    frames = int(tc.get("sample_frames", 49))
    return Servable(cin, lat, int(tc.get("sample_height", 60)) * VAE_SPATIAL,
                    int(tc.get("sample_width", 90)) * VAE_SPATIAL, (frames - 1) // VAE_TEMPORAL + 1)


def check_tokenizer(root) -> None:
    """The T5 tokenizer loads only with sentencepiece (and protobuf for its conversion)."""
    tok = Path(root) / "tokenizer"
    if (tok / "spiece.model").is_file():
        missing = []
        for mod, pkg in (("sentencepiece", "sentencepiece"), ("google.protobuf", "protobuf")):
            try:
                __import__(mod)
            except ImportError:
                missing.append(pkg)
        if missing:
            raise CheckpointError(f"{tok / 'spiece.model'}: loading it needs the {' and '.join(missing)} "
                                  f"package(s); pip install -r requirements.txt (or use envs/refiner.yaml)")
    elif not (tok / "tokenizer.json").is_file():
        raise CheckpointError(f"{tok}: holds neither spiece.model nor tokenizer.json; re-copy the tokenizer/ "
                              "folder of the model")


def check_sizes(s: Servable, *, width_px: int, height_px: int, train_window: int, infer_window: int,
                where: str) -> None:
    """One line naming the sizes the checkpoint serves when the run asks for another."""
    if s.height_px is None:
        return
    if (width_px, height_px) != (s.width_px, s.height_px):
        raise CheckpointError(
            f"{where}: the transformer's learned positional embeddings serve {s.width_px}x{s.height_px} pixels only, "
            f"the run makes {width_px}x{height_px} clips; set scenes.width: {s.width_px} and scenes.height: "
            f"{s.height_px}")
    for key, w in (("refiner.train.latent_window", train_window), ("refiner.infer.window", infer_window)):
        if w != s.window_latent:
            raise CheckpointError(
                f"{where}: {key}={w} latent frames, but the learned positional embeddings serve "
                f"{s.window_latent} latent frames ({s.window_frames} pixel frames) only; set {key}: {s.window_latent}")
