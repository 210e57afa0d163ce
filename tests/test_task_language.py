"""TALAR's task language: Gumbel-softmax, generator/translator shapes and losses, and learning on a toy task."""

import collections
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from benchmarks.supervised_layouts import autodiff_attention_pool
from talar_jax.optim import AdamFit, fit_seeds
from talar_jax.talar import (
    TalarConfig,
    build_task_language_data,
    make_generate_task_language,
    make_train_end_to_end,
    make_train_task_language,
    make_train_translator,
    make_translate,
    prepare_referential_data,
    referential_token_rows,
    sample_referential_batch,
    task_language_quality,
    trim_token_padding,
    with_paraphrases,
)
from talar_jax.task_language import (
    Receiver,
    TaskLanguageGenerator,
    TaskLanguageSpec,
    Translator,
    attention_pool,
    decode_translation,
    gumbel_softmax,
    receiver_logits_per_prefix,
    receiver_logits_per_token,
    translator_loss,
    translator_nll,
)


def test_gumbel_softmax_is_one_hot_with_soft_gradient():
    logits = jnp.array([[0.1, 2.0, -1.0], [3.0, 0.0, 0.0]])
    hard = gumbel_softmax(logits, None)
    np.testing.assert_array_equal(hard, [[0, 1, 0], [1, 0, 0]])
    grad = jax.grad(lambda x: (gumbel_softmax(x, None) * jnp.array([1.0, 2.0, 3.0])).sum())(logits)
    assert np.abs(np.asarray(grad)).sum() > 0  # straight-through: gradient of the soft sample
    samples = jax.vmap(lambda k: gumbel_softmax(jnp.zeros(4), k))(jax.random.split(jax.random.key(0), 4000))
    np.testing.assert_allclose(samples.mean(0), 0.25, atol=0.03)  # uniform logits -> uniform choices


def test_generator_output_layout():
    spec = TaskLanguageSpec(num_predicates=3, num_arguments=2, arg_size=4)
    generator = TaskLanguageGenerator(spec)
    s = jnp.ones((7, 10))
    params = generator.init(jax.random.key(0), s, s, None)
    out = generator.apply(params, s, s * 2, jax.random.key(1))
    assert out.shape == (7, spec.size) == (7, 3 + 2 * 4)
    assert set(np.unique(np.asarray(out)).tolist()) <= {0.0, 1.0}
    np.testing.assert_array_equal(out[:, 3:].reshape(7, 2, 4).sum(-1), 1.0)  # each argument is one-hot


def test_translator_loss_hand_values_and_decoding():
    spec = TaskLanguageSpec(num_predicates=1, num_arguments=1, arg_size=2)
    logits = jnp.array([[0.0, 0.0, 0.0]])
    target = jnp.array([[1.0, 0.0, 1.0]])
    # predicate: -log sigmoid(0) = log 2; argument: -log softmax([0, 0])[1] = log 2
    np.testing.assert_allclose(translator_loss(spec, logits, target), 2 * np.log(2), rtol=1e-6)
    np.testing.assert_array_equal(decode_translation(spec, jnp.array([[2.0, -1.0, 3.0]])), [[1.0, 0.0, 1.0]])
    with pytest.raises(ValueError, match="num_predicates"):
        TaskLanguageSpec(num_predicates=-1)
    with pytest.raises(ValueError, match="at least one"):
        TaskLanguageSpec(num_predicates=0, num_arguments=0)
    goal_code = TaskLanguageSpec(num_predicates=0, num_arguments=1, arg_size=3)  # e.g. a goal one-hot
    np.testing.assert_allclose(
        translator_loss(goal_code, jnp.log(jnp.array([[0.2, 0.5, 0.3]])), jnp.array([[0.0, 1.0, 0.0]])), -np.log(0.5)
    )


def _toy_data(num_goals=4, per_goal=6, tuples=2048, dim=8, seed=0):
    """Goal g moves the state by a goal-specific offset; its sentences embed near a goal vector and their
    tokens are (goal word, shared word)."""
    rng = np.random.default_rng(seed)
    offsets = rng.normal(size=(num_goals, 6)) * 2
    goal_vectors = rng.normal(size=(num_goals, dim))
    sentence_goal = np.repeat(np.arange(num_goals), per_goal)
    sentence_embeddings = goal_vectors[sentence_goal] + 0.3 * rng.normal(size=(len(sentence_goal), dim))
    is_train = np.tile(np.arange(per_goal) < per_goal // 2, num_goals)
    # 2 prefixes per sentence: empty -> goal word (token g), goal word -> shared word (token num_goals)
    prefix_embeddings = np.concatenate([np.zeros((1, dim)), goal_vectors])  # 0: empty, 1+g: after goal word
    prefix_rows = np.stack([np.zeros(num_goals, int), 1 + np.arange(num_goals)], 1)  # (goals, 2)
    prefix_table = np.zeros((len(sentence_goal) * 2, dim))
    next_token = np.zeros(len(sentence_goal) * 2, np.int32)
    for s, g in enumerate(sentence_goal):
        prefix_table[2 * s : 2 * s + 2] = prefix_embeddings[prefix_rows[g]]
        next_token[2 * s : 2 * s + 2] = (g, num_goals)
    train_sentences = np.flatnonzero(is_train)
    ids = rng.choice(train_sentences, tuples)
    states = rng.normal(size=(tuples, 6))
    data = build_task_language_data(
        states=states,
        final_states=states + offsets[sentence_goal[ids]],
        sentence_ids=ids,
        sentence_embeddings=sentence_embeddings,
        prefix_embeddings=prefix_table,
        prefix_next_token=next_token,
        sentence_prefix_start=2 * np.arange(len(sentence_goal)),
        sentence_prefix_count=np.full(len(sentence_goal), 2),
    )
    return data, sentence_goal, is_train, num_goals + 1


def test_talar_learns_a_task_language_that_separates_goals_on_a_toy_task():
    data, sentence_goal, is_train, vocab = _toy_data()
    config = TalarConfig(rg_steps=1500, translator_steps=800, batch_size=128)
    seeds = jax.random.split(jax.random.key(0), 2)
    params, rg_losses = fit_seeds(make_train_task_language(config, vocab), seeds, data, chunks=3, progress=False)
    assert rg_losses.shape == (2, config.rg_steps)
    # Predicting the goal word needs the TL: chance is log(4) for that half of the tokens.
    final = np.asarray(rg_losses[:, -200:].mean(1))
    assert np.all(final < 0.25), final
    assert np.all(final < np.asarray(rg_losses[:, :50].mean(1)))
    generate = jax.vmap(make_generate_task_language(config), in_axes=(0, None, None))
    targets = generate(params["generator"], data.states, data.final_states)
    translator_params, tr_losses = jax.jit(jax.vmap(make_train_translator(config), in_axes=(0, 0, None)))(
        seeds, targets, data
    )
    assert float(tr_losses[:, -100:].mean()) < 0.1 * float(tr_losses[:, :20].mean())
    table = jax.vmap(make_translate(config), in_axes=(0, None))(translator_params, data.sentence_embeddings)
    for seed in range(2):
        quality = task_language_quality(np.asarray(table[seed]), sentence_goal, is_train)
        assert quality["distinct_goal_codes"] == 1.0, quality
        assert quality["train_consistency"] == 1.0, quality
        assert quality["test_matches_train"] >= 0.9, quality
    generated = make_generate_task_language(config)(
        jax.tree.map(lambda x: x[0], params["generator"]), data.states[:4], data.final_states[:4]
    )
    assert generated.shape == (4, config.spec.size)


def test_all_tokens_referential_loss_is_the_mean_over_each_instructions_tokens():
    """rg_all_tokens: one message per tuple, NLL averaged over that instruction's real tokens (padding masked)."""
    data, _, _, vocab = _toy_data(tuples=64)
    counts = np.where(np.arange(len(data.sentence_prefix_count)) % 2 == 0, 2, 1)  # odd sentences: one token
    data = data._replace(sentence_prefix_count=jnp.asarray(counts, jnp.int32))
    config = TalarConfig(batch_size=16, rg_all_tokens=True)
    with pytest.raises(ValueError, match="max_tokens"):
        make_train_task_language(config, vocab)
    fit = make_train_task_language(config, vocab, max_tokens=3)  # padding in every row
    rng = jax.random.key(3)
    params = fit.init_params(jax.random.key(0), data)
    loss = float(fit.loss(params, rng, data))
    rng_batch, rng_prefix, rng_gumbel = jax.random.split(rng, 3)
    rows, _ = sample_referential_batch(rng_batch, rng_prefix, data, config.batch_size)
    message = TaskLanguageGenerator(config.spec, config.generator_hidden, config.gumbel_temperature).apply(
        params["generator"], data.states[rows], data.final_states[rows], rng_gumbel
    )
    receiver = Receiver(vocab, config.receiver_hidden)
    expected = []
    for b, row in enumerate(np.asarray(rows)):
        sentence = int(data.sentence_ids[row])
        per_token = []
        for j in range(counts[sentence]):
            prefix = int(data.sentence_prefix_start[sentence]) + j
            logits = receiver.apply(params["receiver"], message[b], data.prefix_embeddings[prefix])
            per_token.append(-float(jax.nn.log_softmax(logits)[data.prefix_next_token[prefix]]))
        expected.append(np.mean(per_token))
    assert len(set(counts[np.asarray(data.sentence_ids[rows])])) == 2  # the batch mixes both lengths
    np.testing.assert_allclose(loss, np.mean(expected), rtol=1e-5)
    # two token slots hold every token of these instructions: the same loss without the padding slot
    slotted = make_train_task_language(dataclasses.replace(config, rg_token_slots=2), vocab, max_tokens=3)
    np.testing.assert_allclose(float(slotted.loss(params, rng, data)), loss, rtol=1e-5)


def test_token_slots_draw_each_token_with_probability_slots_over_count():
    """rg_token_slots = K: an instruction of c > K tokens lists K distinct tokens, each drawn with probability K / c
    (so the slot mean is unbiased for the token mean); one of c <= K tokens lists every token once."""
    data, _, _, _ = _toy_data(tuples=8)
    counts = np.array([7, 2] * (len(data.sentence_prefix_count) // 2), np.int32)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int32)
    data = data._replace(
        sentence_prefix_count=jnp.asarray(counts),
        sentence_prefix_start=jnp.asarray(starts),
        sentence_ids=jnp.asarray([0, 1], jnp.int32),  # tuple 0 reads sentence 0 (7 tokens), tuple 1 sentence 1 (2)
    )
    rows = jnp.arange(2)
    draws = 20_000
    prefix, mask = jax.vmap(lambda key: referential_token_rows(rows, data, 7, key, slots=3))(
        jax.random.split(jax.random.key(0), draws)
    )
    prefix, mask = np.asarray(prefix), np.asarray(mask)
    assert prefix.shape == mask.shape == (draws, 2, 3)
    long_rows = prefix[:, 0] - starts[0]  # the 7-token instruction
    assert mask[:, 0].all() and ((long_rows >= 0) & (long_rows < 7)).all()
    assert (np.diff(np.sort(long_rows, axis=1), axis=1) > 0).all()  # K distinct tokens
    frequency = np.bincount(long_rows.reshape(-1), minlength=7) / draws
    np.testing.assert_allclose(frequency, 3 / 7, atol=0.02)
    np.testing.assert_array_equal(mask[:, 1], [[True, True, False]] * draws)  # the 2-token one: both, then padding
    np.testing.assert_array_equal(prefix[:, 1, :2] - starts[1], [[0, 1]] * draws)
    with pytest.raises(ValueError, match="rng"):
        referential_token_rows(rows, data, 7, None, slots=3)


def test_per_prefix_receiver_and_per_sentence_translator_equal_the_per_row_networks():
    """The cheaper layouts the fits use: per prefix or per sentence when there are fewer distinct ones than rows, and
    the split first layer of the receiver otherwise."""
    data, _, _, vocab = _toy_data(tuples=64)
    assert data.prefix_table.shape[0] == 5  # the empty prefix and one per goal word, deduplicated
    receiver = Receiver(vocab, (32, 16))
    message = jnp.asarray(np.random.default_rng(1).integers(0, 2, (7, 14)), jnp.float32)
    params = receiver.init(jax.random.key(0), message, data.prefix_embeddings[:7])
    used = np.asarray(data.sentence_prefix_start[data.dataset_sentences])  # first prefix of each used sentence
    prefix = jnp.asarray(np.random.default_rng(2).choice(np.concatenate([used, used + 1]), (7, 3)))
    expected = receiver.apply(params, jnp.broadcast_to(message[:, None], (7, 3, 14)), data.prefix_embeddings[prefix])
    cheap = receiver_logits_per_prefix(params, message, data.prefix_table, data.prefix_table_index[prefix])
    np.testing.assert_allclose(cheap, expected, rtol=1e-5, atol=1e-5)
    per_token = receiver_logits_per_token(params, message, data.prefix_embeddings[prefix])
    np.testing.assert_allclose(per_token, expected, rtol=1e-5, atol=1e-5)

    config = TalarConfig(batch_size=128)  # 12 training sentences < 128 tuples: the per-sentence layout
    assert data.dataset_sentences.shape[0] < config.batch_size
    fit = make_train_translator(config)
    targets = jnp.asarray(np.random.default_rng(3).integers(0, 2, (64, config.spec.size)), jnp.float32)
    translator_params = fit.init_params(jax.random.key(1), targets, data)
    rng = jax.random.key(4)
    rows = jax.random.randint(rng, (config.batch_size,), 0, data.states.shape[0])
    logits = Translator(config.spec, config.translator_hidden).apply(
        translator_params, data.sentence_embeddings[data.sentence_ids[rows]]
    )
    np.testing.assert_allclose(
        fit.loss(translator_params, rng, targets, data), translator_loss(config.spec, logits, targets[rows]), rtol=1e-5
    )


def test_end_to_end_talar_adds_the_translator_loss_and_learns_the_toy_task():
    """Appendix E.6: one fit of generator, receiver and translator; its loss is L_RG plus Eq. 3 on the same tuples
    against the generator's deterministic TL, and on the toy task its translator separates the goals."""
    data, sentence_goal, is_train, vocab = _toy_data()
    config = TalarConfig(rg_steps=1200, batch_size=128)
    fit = make_train_end_to_end(config, vocab)
    game = make_train_task_language(config, vocab)
    params = fit.init_params(jax.random.key(0), data)
    assert set(params) == {"generator", "receiver", "translator"}
    rng = jax.random.key(5)
    rows, _ = sample_referential_batch(*jax.random.split(rng, 3)[:2], data, config.batch_size)
    target = TaskLanguageGenerator(config.spec, config.generator_hidden, config.gumbel_temperature).apply(
        params["generator"], data.states[rows], data.final_states[rows], None
    )
    logits = Translator(config.spec, config.translator_hidden).apply(
        params["translator"], data.sentence_embeddings[data.sentence_ids[rows]]
    )
    expected = game.loss(params, rng, data) + translator_loss(config.spec, logits, target)
    np.testing.assert_allclose(fit.loss(params, rng, data), expected, rtol=1e-5)

    trained, losses = jax.jit(fit)(jax.random.key(1), data)
    assert float(losses[-100:].mean()) < float(losses[:20].mean())
    table = make_translate(config)(trained["translator"], data.sentence_embeddings)
    quality = task_language_quality(np.asarray(table), sentence_goal, is_train)
    assert quality["distinct_goal_codes"] == 1.0 and quality["decodable_test"] >= 0.9, quality


def test_full_batch_translator_loss_is_the_expected_sampled_loss():
    """translator_full_batch: one row per distinct instruction with its tuples' mean target, weighted by their
    share, equals the mean per-tuple loss over the whole dataset; with paraphrases, the mix of the instruction's and
    its paraphrases' losses the sampled batches draw with ``paraphrase_probability``."""
    data, _, _, _ = _toy_data(tuples=300)
    config = TalarConfig(translator_full_batch=True, paraphrase_probability=0.3)
    fit = make_train_translator(config)
    targets = jnp.asarray(np.random.default_rng(3).integers(0, 2, (300, config.spec.size)), jnp.float32)
    params = fit.init_params(jax.random.key(1), targets, data)
    translator = Translator(config.spec, config.translator_hidden)
    per_tuple = translator_nll(
        config.spec, translator.apply(params, data.sentence_embeddings[data.sentence_ids]), targets
    )
    np.testing.assert_allclose(fit.loss(params, jax.random.key(0), targets, data), per_tuple.mean(), rtol=1e-5)

    features = np.random.default_rng(4).normal(size=(2 * len(data.dataset_sentences), 8))
    paraphrased = with_paraphrases(data, features, np.repeat(np.asarray(data.dataset_sentences), 2))
    variant_rows = paraphrased.sentence_variants[data.sentence_ids]  # (N, 2)
    variant_nll = translator_nll(
        config.spec, translator.apply(params, paraphrased.sentence_embeddings[variant_rows]), targets[:, None, :]
    ).mean(-1)
    expected = (0.7 * per_tuple + 0.3 * variant_nll).mean()
    np.testing.assert_allclose(fit.loss(params, jax.random.key(0), targets, paraphrased), expected, rtol=1e-5)
    assert "batch_size" not in config.translator_fields() and "batch_size" in TalarConfig().translator_fields()


def test_receiver_prefix_dims_projects_onto_the_training_prefixes_principal_axes():
    data, _, _, vocab = _toy_data(tuples=64, dim=8)
    assert prepare_referential_data(TalarConfig(), data) is data  # the paper's receiver: untouched
    rank = np.linalg.matrix_rank(np.asarray(data.prefix_table) - np.asarray(data.prefix_table).mean(0))
    full = prepare_referential_data(TalarConfig(receiver_prefix_dims=rank), data)
    assert full.prefix_embeddings.shape == (data.prefix_embeddings.shape[0], rank)

    def distances(x):
        x = np.asarray(x, np.float64)
        return np.linalg.norm(x[:, None] - x[None], axis=-1)

    # all principal axes of a rank-r table: a rotation of the centred prefixes, so distances are kept ...
    np.testing.assert_allclose(distances(full.prefix_table), distances(data.prefix_table), atol=1e-4)
    # ... and one axis keeps the direction of largest spread
    one = np.asarray(prepare_referential_data(TalarConfig(receiver_prefix_dims=1), data).prefix_table)[:, 0]
    centred = np.asarray(data.prefix_table) - np.asarray(data.prefix_table).mean(0)
    assert one.var() == pytest.approx(np.linalg.svd(centred, compute_uv=False)[0] ** 2 / len(centred), rel=1e-4)
    assert full.sentence_embeddings is data.sentence_embeddings  # the translator's input is not touched

    config = TalarConfig(receiver_prefix_dims=2, rg_steps=5, batch_size=16)
    fit = make_train_task_language(config, vocab)
    with pytest.raises(ValueError, match="prepare_referential_data"):
        fit.init_params(jax.random.key(0), data)
    params, losses = fit(jax.random.key(0), prepare_referential_data(config, data))
    assert params["receiver"]["params"]["ReluMLP_0"]["dense_0"]["kernel"].shape[0] == config.spec.size + 2
    assert np.isfinite(np.asarray(losses)).all()
    capped = prepare_referential_data(TalarConfig(receiver_prefix_dims=100), data)  # more axes than prefixes
    assert capped.prefix_table.shape == (5, 5)


def test_task_language_quality_on_a_hand_built_table():
    goal_ids = np.array([0, 0, 1, 1, 2, 0, 1, 2])
    is_train = np.array([True, True, True, True, True, False, False, False])
    a, b = [1, 0, 0], [0, 1, 0]
    table = np.array([a, a, b, b, b, a, a, b])  # goals 1 and 2 share code b; test of goal 1 gets goal 0's code
    quality = task_language_quality(table, goal_ids, is_train)
    assert quality["train_consistency"] == 1.0
    assert quality["distinct_goal_codes"] == pytest.approx(1 / 3)
    assert quality["test_matches_train"] == pytest.approx(2 / 3)  # goals 0 and 2 match, goal 1 does not
    assert quality["decodable_train"] == pytest.approx(4 / 5)  # code b names goal 1 (2 votes to 1)
    assert quality["decodable_test"] == pytest.approx(1 / 3)  # only goal 0's test instruction is decoded


def test_chunked_fit_equals_one_scan_and_prints_progress(capsys):
    """fit_seeds' chunks (with their progress lines) give the same result as one scan: step keys are fold_in(i)."""

    def loss(params, rng, centres):
        noise = jax.random.normal(rng, params.shape)
        return jnp.sum((params - centres - 0.1 * noise) ** 2)

    fit = AdamFit(lambda rng, centres: jax.random.normal(rng, centres.shape), loss, 0.2, steps=60)
    keys = jax.random.split(jax.random.key(3), 2)
    centres = jnp.array([[1.0, -2.0], [3.0, 0.5]])
    params, losses = fit_seeds(fit, keys, centres, in_axes=(0,), label="toy", chunks=3)
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("toy: step")]
    assert len(lines) == 3 and "step 60/60" in lines[-1]
    whole_params, whole_losses = jax.vmap(fit)(keys, centres)
    np.testing.assert_allclose(params, whole_params, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(losses, whole_losses, rtol=1e-5, atol=1e-6)
    assert losses.shape == (2, 60) and np.all(losses[:, -5:].mean(1) < 0.1 * losses[:, :5].mean(1))
    np.testing.assert_allclose(params, centres, atol=0.2)
    with pytest.raises(ValueError, match="1 inputs but 2 in_axes"):
        fit_seeds(fit, keys, centres, in_axes=(0, None))


def test_an_interrupted_fit_resumes_from_its_checkpoint_and_ends_where_an_uninterrupted_one_does(tmp_path, capsys):
    def loss(params, rng, centres):
        return jnp.sum((params - centres - 0.1 * jax.random.normal(rng, params.shape)) ** 2)

    fit = AdamFit(lambda rng, centres: jax.random.normal(rng, centres.shape), loss, 0.2, steps=60)
    keys = jax.random.split(jax.random.key(3), 2)  # typed keys: the checkpoint stores their raw data
    centres = jnp.array([[1.0, -2.0], [3.0, 0.5]])
    whole_params, whole_losses = fit_seeds(fit, keys, centres, in_axes=(0,), chunks=3, progress=False)
    checkpoint = tmp_path / "checkpoints" / "fit.msgpack"
    # "interrupted" after 20 of the 60 steps: a fit of 20 steps leaves its state in the checkpoint
    fit_seeds(dataclasses.replace(fit, steps=20), keys, centres, in_axes=(0,), chunks=1, checkpoint=checkpoint)
    assert checkpoint.is_file()
    capsys.readouterr()
    params, losses = fit_seeds(fit, keys, centres, in_axes=(0,), chunks=3, checkpoint=checkpoint, label="toy")
    out = capsys.readouterr().out
    assert "resumed at step 20/60" in out and "step 40/60" in out
    np.testing.assert_allclose(params, whole_params, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(losses, whole_losses, rtol=1e-5, atol=1e-6)
    assert losses.shape == (2, 60)


def test_token_translator_finds_the_word_its_context_marks_where_a_mean_pool_cannot():
    """Toy 'sentences' of contextual token states: two colour words whose states differ only by a relation marker on
    the reference colour, in either order, padded with zero rows. Which colour is the reference is invisible to the
    mean of the tokens (colour_a + colour_b + markers, symmetric in the two), so the paper's pooled-input translator
    stays near chance, while the attention-pooling translator (``reads_tokens``) learns it; padding never matters."""
    rng = np.random.default_rng(0)
    colours, dim, slots = 4, 16, 6
    colour_vectors, marker = rng.normal(size=(colours, dim)), rng.normal(size=dim)
    pairs = [(a, b) for a in range(colours) for b in range(colours) if a != b]
    states, targets = np.zeros((2 * len(pairs), slots, dim), np.float32), []
    for i, (subject, reference) in enumerate(pairs):
        for j, order in enumerate(((0, 2), (2, 0))):  # subject first or reference first, at other positions
            row = states[2 * i + j]
            row[order[0]] = colour_vectors[subject]
            row[order[1]] = colour_vectors[reference] + marker
            row[1] = marker  # the relation word itself
            targets.append(reference)
    spec = TaskLanguageSpec(num_predicates=0, num_arguments=1, arg_size=colours)
    targets = jax.nn.one_hot(np.array(targets), colours)
    inputs = {True: jnp.asarray(states), False: jnp.asarray(states.sum(1) / 3.0)}  # the mean over real tokens
    accuracy = {}
    for reads_tokens in (True, False):
        translator = Translator(spec, (64, 64), reads_tokens=reads_tokens)
        x = inputs[reads_tokens]
        params = translator.init(jax.random.PRNGKey(0), x[:1])
        optimiser = optax.adam(3e-3)
        state = optimiser.init(params)

        @jax.jit
        def step(params, state, translator=translator, x=x):
            grads = jax.grad(lambda p: translator_loss(spec, translator.apply(p, x), targets))(params)
            updates, state = optimiser.update(grads, state)
            return optax.apply_updates(params, updates), state

        for _ in range(400):
            params, state = step(params, state)
        predicted = np.asarray(translator.apply(params, x)).argmax(-1)
        accuracy[reads_tokens] = float((predicted == np.asarray(targets).argmax(-1)).mean())
        if reads_tokens:  # more padding slots change nothing
            padded = jnp.concatenate([x, jnp.zeros((x.shape[0], 3, dim))], axis=1)
            np.testing.assert_allclose(translator.apply(params, padded), translator.apply(params, x), atol=1e-5)
            holder = collections.namedtuple("Holder", "sentence_embeddings")  # what trim_token_padding reads
            assert trim_token_padding(holder(padded)).sentence_embeddings.shape == (x.shape[0], 3, dim)
    assert accuracy[True] == 1.0, accuracy
    assert accuracy[False] <= 0.6, accuracy


def test_attention_pool_gradient_matches_autodiff_with_padding_and_batch_axes():
    rng = np.random.default_rng(0)
    tokens = rng.normal(size=(2, 3, 5, 6)).astype(np.float32)
    tokens[:, :, 3:] = 0.0  # padding slots
    tokens[1, 2] = 0.0  # a sentence with no token at all
    kernel, bias = rng.normal(size=(6, 4)).astype(np.float32), rng.normal(size=4).astype(np.float32)
    cotangent = jnp.asarray(rng.normal(size=(2, 3, 4, 6)), jnp.float32)
    args = (jnp.asarray(tokens), jnp.asarray(kernel), jnp.asarray(bias))
    np.testing.assert_allclose(attention_pool(*args), autodiff_attention_pool(*args), rtol=1e-5, atol=1e-6)
    grads = jax.grad(lambda *a: (attention_pool(*a) * cotangent).sum(), argnums=(0, 1, 2))(*args)
    expected = jax.grad(lambda *a: (autodiff_attention_pool(*a) * cotangent).sum(), argnums=(0, 1, 2))(*args)
    for got, want in zip(grads, expected):
        np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-5)
    assert np.abs(np.asarray(grads[1])).sum() > 0  # the scores' kernel learns
    under_vmap = jax.vmap(lambda k: jax.grad(lambda k: (attention_pool(args[0], k, args[2]) * cotangent).sum())(k))
    np.testing.assert_allclose(under_vmap(jnp.stack([args[1]] * 2))[1], grads[1], rtol=1e-5, atol=1e-6)


def test_translator_scores_keep_the_dense_layers_parameters():
    """Trained token translators (shipped agents among them) store the scores as an ``nn.Dense``'s ``Dense_0``: the
    same tree, initialised to the same values, as a translator scoring with ``nn.Dense``."""
    import flax.linen as nn

    from talar_jax.task_language import ReluMLP

    spec = TaskLanguageSpec()

    class DenseScoresTranslator(nn.Module):
        @nn.compact
        def __call__(self, x):
            nn.Dense(4)(x)
            return ReluMLP((8, spec.size))(x.reshape(*x.shape[:-2], -1)[..., :20])

    tokens = jnp.ones((1, 5, 5))
    params = Translator(spec, (8,), reads_tokens=True).init(jax.random.key(3), tokens)
    reference = DenseScoresTranslator().init(jax.random.key(3), tokens)
    np.testing.assert_array_equal(params["params"]["Dense_0"]["kernel"], reference["params"]["Dense_0"]["kernel"])
    np.testing.assert_array_equal(params["params"]["Dense_0"]["bias"], reference["params"]["Dense_0"]["bias"])
    assert jax.tree.structure(params) == jax.tree.structure(reference)
