#!/usr/bin/env python
"""Encode the empty prompt once with the checkpoint's T5 (the paper preset's fixed text input).

  encode_empty_prompt.py --config-json @refiner.json --out results/refiner/empty_prompt.pt

Reads {model.model_path}/tokenizer and text_encoder, writes the (1, max_text_seq_length,
text_embed_dim) float32 embedding to OUT (temporary name, then rename). Training, inference and the
relight command read it through model.empty_prompt_cache instead of loading T5-XXL (~19 GB in fp32)
in every job. Runs on the CPU (one forward pass of 226 tokens).
"""

import argparse
import json
from pathlib import Path

import _cli  # puts the repository on sys.path; run() is the one error path

from lightcrafter.refiner import MissingWeightsError, resolve_config
from lightcrafter.refiner.model import empty_prompt_embedding, require_model_path


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config-json", default="{}")
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    cfg = resolve_config(_cli.json_arg(a.config_json))
    out = Path(a.out)
    out.unlink(missing_ok=True)  # recomputed whenever the rule runs
    cfg["model"]["empty_prompt_cache"] = str(out)
    tc = json.loads((require_model_path(cfg) / "transformer" / "config.json").read_text())
    emb = empty_prompt_embedding(cfg, int(tc["max_text_seq_length"]), int(tc["text_embed_dim"]))
    print(f"encode_empty_prompt: {tuple(emb.shape)} -> {out}")
    return 0


if __name__ == "__main__":
    _cli.run(main, "encode_empty_prompt", (MissingWeightsError, KeyError, ValueError))
