"""A tiny CogVideoX-I2V checkpoint in the released diffusers folder layout, for rehearsals.

The paper preset loads CogVideoX-5B-I2V from a local folder; no weights can be downloaded here, so
the rehearsal (``scripts/rehearse_refiner.py``, tests/test_refiner_paper_rehearsal.py) writes a
random-initialised stand-in with the same *structure* and runs the paper preset on it through the
same ``from_pretrained`` code:

* written by ``CogVideoXImageToVideoPipeline.save_pretrained``: ``model_index.json``, ``transformer/``,
  ``vae/``, ``text_encoder/``, ``tokenizer/``, ``scheduler/`` (the released layout);
* a ``CogVideoXTransformer3DModel`` with ``in_channels = 2 x 16`` and, as 5B-I2V has, rotary *and*
  learned positional embeddings (fixed to ``height x width`` pixels and ``frames`` frames);
* an ``AutoencoderKLCogVideoX`` with 16 latent channels, 8x spatial and 4x temporal compression;
* a ``T5EncoderModel`` whose width is the transformer's ``text_embed_dim``;
* ``tokenizer/spiece.model``, a SentencePiece model trained on the spot (``sentencepiece`` package);
* the 5B checkpoints' scheduler (``CogVideoXDDIMScheduler`` with COGVIDEOX_5B_SCHEDULER).

Sizes: 32 x 48 pixels (4 x 6 latents, 2 x 3 tokens) and 49 frames (13 latent frames) by default.
"""

from __future__ import annotations

from pathlib import Path

from .config import COGVIDEOX_5B_SCHEDULER

# The fields of CogVideoX-5B-I2V's transformer/config.json that decide what it can serve.
COGVIDEOX_5B_I2V_TRANSFORMER = {
    "in_channels": 32, "out_channels": 16, "patch_size": 2, "sample_height": 60, "sample_width": 90,
    "sample_frames": 49, "temporal_compression_ratio": 4, "max_text_seq_length": 226, "text_embed_dim": 4096,
    "use_rotary_positional_embeddings": True, "use_learned_positional_embeddings": True,
}


# CogVideoX-5B-I2V's transformer widths (its transformer/config.json): ~5.6e9 parameters.
COGVIDEOX_5B_WIDTHS = {"num_attention_heads": 48, "attention_head_dim": 64, "time_embed_dim": 512,
                       "text_embed_dim": 4096, "num_layers": 42}


def transformer_kwargs(*, height_px: int, width_px: int, frames: int, text_len: int = 226,
                       full_size: bool = False) -> dict:
    """The stand-in's CogVideoXTransformer3DModel arguments: tiny widths, or 5B-I2V's with ``full_size``."""
    widths = (COGVIDEOX_5B_WIDTHS if full_size else
              {"num_attention_heads": 2, "attention_head_dim": 16, "time_embed_dim": 32, "text_embed_dim": 32,
               "num_layers": 1})
    return dict(**widths, in_channels=32, out_channels=16, sample_width=width_px // 8, sample_height=height_px // 8,
                sample_frames=frames, patch_size=2, temporal_compression_ratio=4, max_text_seq_length=text_len,
                use_rotary_positional_embeddings=True, use_learned_positional_embeddings=True)


def write_tiny_checkpoint(root, *, height_px: int = 32, width_px: int = 48, frames: int = 49, seed: int = 0,
                          text_len: int = 226, full_size: bool = False, device: str = "cpu") -> Path:
    """Write the stand-in checkpoint to ``root`` (module docstring); returns ``root``.

    ``full_size``: the transformer at CogVideoX-5B-I2V's widths (COGVIDEOX_5B_WIDTHS, bf16 like the release,
    ~11 GB) and the VAE at diffusers' AutoencoderKLCogVideoX defaults (CogVideoX's VAE) with 5B's latent
    scaling factor 0.7, still random: for
    measuring memory and seconds of the paper preset at full size (benchmarks/refiner_step.py). The T5
    encoder stays one layer, at the transformer's text width. ``device``: where the weights are
    initialised (``cuda`` makes the 5B initialisation take seconds instead of minutes)."""
    import tempfile

    import sentencepiece as spm
    import torch
    from diffusers import (AutoencoderKLCogVideoX, CogVideoXDDIMScheduler, CogVideoXImageToVideoPipeline,
                           CogVideoXTransformer3DModel)
    from transformers import T5Config, T5EncoderModel, T5Tokenizer

    if height_px % 16 or width_px % 16 or (frames - 1) % 4:
        raise ValueError(f"{width_px}x{height_px}x{frames}: sizes must be multiples of 16 and frames 4k+1")
    root = Path(root)
    torch.manual_seed(seed)
    kwargs = transformer_kwargs(height_px=height_px, width_px=width_px, frames=frames, text_len=text_len,
                                full_size=full_size)
    text_dim = kwargs["text_embed_dim"]
    with torch.device(device):
        transformer = CogVideoXTransformer3DModel(**kwargs)
        if full_size:
            transformer = transformer.to(torch.bfloat16)
            vae = AutoencoderKLCogVideoX(latent_channels=16, temporal_compression_ratio=4,
                                         scaling_factor=0.7).to(torch.bfloat16)  # 5B's latent scale
        else:
            vae = AutoencoderKLCogVideoX(
                in_channels=3, out_channels=3, latent_channels=16, block_out_channels=(8, 8, 8, 8),
                down_block_types=("CogVideoXDownBlock3D",) * 4, up_block_types=("CogVideoXUpBlock3D",) * 4,
                layers_per_block=1, norm_num_groups=2, temporal_compression_ratio=4)
    text_encoder = T5EncoderModel(T5Config(vocab_size=128, d_model=text_dim, d_kv=8, d_ff=64, num_layers=1,
                                           num_heads=4, relative_attention_num_buckets=8))
    with tempfile.TemporaryDirectory() as tmp:
        words = ("light shadow video scene relight proxy render frame colour surface metal rough "
                 "glossy diffuse camera orbit table chair lamp window").split()
        corpus = [" ".join(words[(i * k) % len(words)] for k in range(1, 9)) for i in range(200)]
        spm.SentencePieceTrainer.train(sentence_iterator=iter(corpus), model_prefix=f"{tmp}/spiece",
                                       vocab_size=48, model_type="unigram", pad_id=0, eos_id=1, unk_id=2,
                                       bos_id=-1, minloglevel=2,
                                       # a soft limit: sentencepiece 0.2.2 reaches only 46 pieces here
                                       hard_vocab_limit=False)
        tokenizer = T5Tokenizer(vocab_file=f"{tmp}/spiece.model", extra_ids=0, model_max_length=text_len)
        scheduler = CogVideoXDDIMScheduler(**{k: v for k, v in COGVIDEOX_5B_SCHEDULER.items()})
        pipe = CogVideoXImageToVideoPipeline(tokenizer=tokenizer, text_encoder=text_encoder, vae=vae,
                                             transformer=transformer, scheduler=scheduler)
        pipe.save_pretrained(root)
        # the released tokenizer/ holds spiece.model and no tokenizer.json, so loading it converts the
        # SentencePiece model (which needs sentencepiece and protobuf): keep exactly that
        import shutil

        shutil.copy(f"{tmp}/spiece.model", root / "tokenizer" / "spiece.model")
        (root / "tokenizer" / "tokenizer.json").unlink(missing_ok=True)
    return root
