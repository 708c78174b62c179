"""Independent reference for inssplat-text: all-MiniLM-L6-v2 sentence embeddings in numpy.

Reads the same model.safetensors and tokenizer.json that the Rust crate loads, tokenizes with
the Python `tokenizers` package, runs the BERT encoder written out below in float64 (no torch,
no transformers, no candle), mean-pools over the attention mask and L2-normalizes. It prints
the vectors as a Rust module, saved as text/tests/reference/vectors.rs for the crate's tests.

Run once (nothing is downloaded; the model folder is the one scripts/setup installs):

    python -m venv /tmp/ref && /tmp/ref/bin/pip install numpy safetensors tokenizers
    source .deps/env && /tmp/ref/bin/python text/tests/reference/minilm_reference.py \
        > text/tests/reference/vectors.rs && cargo fmt -p inssplat-text
"""

import json
import math
import os
import sys

import numpy as np
from safetensors.numpy import load_file
from tokenizers import Tokenizer

SENTENCES = ["a red armchair next to the window", "lamp"]


def layer_norm(x, w, b, eps):
    mean = x.mean(axis=-1, keepdims=True)
    var = ((x - mean) ** 2).mean(axis=-1, keepdims=True)
    return (x - mean) / np.sqrt(var + eps) * w + b


def linear(x, t, name):
    return x @ t[name + ".weight"].T + t[name + ".bias"]


ERF = np.vectorize(math.erf)


def gelu(x):
    return 0.5 * x * (1.0 + ERF(x / math.sqrt(2.0)))


def encode(t, cfg, ids):
    """Last hidden states (seq, hidden) of one unpadded sequence."""
    n = len(ids)
    eps = cfg["layer_norm_eps"]
    heads = cfg["num_attention_heads"]
    x = (
        t["embeddings.word_embeddings.weight"][ids]
        + t["embeddings.position_embeddings.weight"][:n]
        + t["embeddings.token_type_embeddings.weight"][0]
    )
    x = layer_norm(x, t["embeddings.LayerNorm.weight"], t["embeddings.LayerNorm.bias"], eps)
    d = x.shape[1] // heads
    for i in range(cfg["num_hidden_layers"]):
        p = f"encoder.layer.{i}."
        q = linear(x, t, p + "attention.self.query").reshape(n, heads, d).transpose(1, 0, 2)
        k = linear(x, t, p + "attention.self.key").reshape(n, heads, d).transpose(1, 0, 2)
        v = linear(x, t, p + "attention.self.value").reshape(n, heads, d).transpose(1, 0, 2)
        s = q @ k.transpose(0, 2, 1) / math.sqrt(d)
        s = np.exp(s - s.max(axis=-1, keepdims=True))
        s = s / s.sum(axis=-1, keepdims=True)
        ctx = (s @ v).transpose(1, 0, 2).reshape(n, heads * d)
        a = linear(ctx, t, p + "attention.output.dense") + x
        x = layer_norm(
            a, t[p + "attention.output.LayerNorm.weight"], t[p + "attention.output.LayerNorm.bias"], eps
        )
        h = gelu(linear(x, t, p + "intermediate.dense"))
        o = linear(h, t, p + "output.dense") + x
        x = layer_norm(o, t[p + "output.LayerNorm.weight"], t[p + "output.LayerNorm.bias"], eps)
    return x


def main():
    folder = os.environ.get("INSSPLAT_TEXT_MODEL")
    if not folder:
        sys.exit("set INSSPLAT_TEXT_MODEL (source .deps/env)")
    t = {k: v.astype(np.float64) for k, v in load_file(os.path.join(folder, "model.safetensors")).items()}
    with open(os.path.join(folder, "config.json")) as f:
        cfg = json.load(f)
    tok = Tokenizer.from_file(os.path.join(folder, "tokenizer.json"))
    tok.no_padding()
    print("//! Reference all-MiniLM-L6-v2 embeddings, written by minilm_reference.py beside this")
    print("//! file: an independent numpy (float64) BERT forward over the same model.safetensors")
    print("//! and tokenizer.json, tokenized by the Python `tokenizers` package. Do not edit.")
    print()
    print("/// (sentence, unit-length 384-d embedding).")
    print("pub const REFERENCE: [(&str, [f32; 384]); %d] = [" % len(SENTENCES))
    for sentence in SENTENCES:
        ids = tok.encode(sentence).ids
        # Unpadded, so every token is attended and the mean pool is a plain mean.
        e = encode(t, cfg, ids).mean(axis=0)
        e = e / np.linalg.norm(e)
        print(f"    // token ids {ids}")
        print("    (")
        print(f"        {json.dumps(sentence)},")
        print("        [")
        for row in range(0, len(e), 8):
            print("            " + " ".join(f"{v:.7f}".rstrip("0") + "," for v in e[row : row + 8]))
        print("        ],")
        print("    ),")
    print("];")


if __name__ == "__main__":
    main()
