"""Stage keys come from exactly the settings a stage reads: change one and the stage reruns, change another and
it is reused (the keys are computed without running anything)."""

import dataclasses
from pathlib import Path

import pytest

from experiments.config import KEY_EXCLUDED_FIELDS, ExperimentConfig, default_config, resolve
from experiments.methods import method_names
from experiments.pipeline import stage_keys
from talar_jax.ppo import PPOConfig
from talar_jax.talar import TalarConfig
from talar_jax.task_language import TaskLanguageSpec

UPSTREAM, CACHE = "oracle-key", "cache-key"


def _changed(value, name):
    """A different valid value of a config field."""
    if isinstance(value, bool):
        return not value
    if isinstance(value, int):
        return value * 2 if value else 3
    if isinstance(value, float):
        return value * 0.5 if value else 0.25
    if name == "reuse_stages":
        return (Path("."),)
    if isinstance(value, tuple):
        return tuple(v * 2 for v in value)
    if isinstance(value, TaskLanguageSpec):
        return dataclasses.replace(value, num_predicates=value.num_predicates + 2)
    if value is None:
        return {"rg_batch_size": 32, "num_patterns": 5, "encoder": "/some/bert", "physics": "mjx"}.get(name, 7)
    if isinstance(value, dict):
        return {**value, "posture_targets": "talar"} if value else {"noise_ratio": "0.0"}
    if name == "sentence_readout":
        return "sentence"
    if name == "physics":
        return "mjx" if value == "c" else "c"
    if name == "out":
        return value / "elsewhere"
    raise AssertionError(f"no change defined for {name}={value!r}")


def _variants(config: ExperimentConfig):
    """(dotted field name, config with that one field changed) for every leaf of a resolved config."""
    for field in dataclasses.fields(config):
        value = getattr(config, field.name)
        if field.name in ("env", "method"):
            continue
        if isinstance(value, (TalarConfig, PPOConfig)):
            for sub in dataclasses.fields(value):
                if isinstance(value, PPOConfig) and sub.name in ("num_seeds", "seed"):
                    continue  # resolve() sets them from seeds / seed
                changed = dataclasses.replace(value, **{sub.name: _changed(getattr(value, sub.name), sub.name)})
                yield f"{field.name}.{sub.name}", dataclasses.replace(config, **{field.name: changed})
        else:
            yield field.name, dataclasses.replace(config, **{field.name: _changed(value, field.name)})


def _keys(config):
    return stage_keys(resolve(config), UPSTREAM, CACHE)


RG_READS = {
    "quick",
    "seeds",
    "seed",
    "talar.spec",
    "talar.generator_hidden",
    "talar.receiver_hidden",
    "talar.receiver_prefix_dims",
    "talar.gumbel_temperature",
    "talar.rg_learning_rate",
    "talar.rg_batch_size",
    "talar.rg_steps",
    "talar.rg_all_tokens",
    "talar.rg_token_slots",
}  # quick: its smoke budgets shorten the game
TRANSLATOR_READS = RG_READS | {
    "sentence_readout",
    "talar.translator_hidden",
    "talar.translator_learning_rate",
    "talar.batch_size",
    "talar.translator_steps",
    "talar.translator_paraphrases",
    "talar.translator_full_batch",
    "talar.translator_tokens",
}
PARAPHRASE_READS = {
    "talar.paraphrase_probability",
    "talar.paraphrase_seed",
    "talar.paraphrase_unknown_words",
    "talar.paraphrase_front_phrases",
}
# ... read only with paraphrases on (CLEVR's recipe has them on; the next tests)


@pytest.mark.parametrize("method", list(method_names()))
def test_the_ifp_reruns_when_any_setting_changes_and_not_for_out_or_progress(method):
    base = default_config("clevr", method=method, physics="c")
    reference = _keys(base)
    for name, variant in _variants(base):
        changed = _keys(variant)["ifp"] != reference["ifp"]
        assert changed == (name not in KEY_EXCLUDED_FIELDS), f"{method}: changing {name} -> ifp rerun {changed}"


def test_referential_game_and_translator_keys_follow_exactly_what_they_read():
    base = default_config("clevr", physics="c")
    assert base.talar.translator_paraphrases > 0
    translator_reads = TRANSLATOR_READS | PARAPHRASE_READS
    reference = _keys(base)
    for name, variant in _variants(base):
        keys = _keys(variant)
        rg_changed = keys["talar/task_language"] != reference["talar/task_language"]
        translator_changed = keys["talar/translator"] != reference["talar/translator"]
        assert rg_changed == (name in RG_READS), f"changing {name}: referential game rerun {rg_changed}"
        assert translator_changed == (name in translator_reads), f"changing {name}: translator {translator_changed}"


def test_paraphrase_settings_reach_the_translator_key_only_when_paraphrases_are_on():
    clevr = default_config("clevr", physics="c")
    base = dataclasses.replace(clevr, talar=dataclasses.replace(clevr.talar, translator_paraphrases=0))
    on = dataclasses.replace(base, talar=dataclasses.replace(base.talar, translator_paraphrases=8))
    reference = _keys(on)
    toggles = ({name: not getattr(on.talar, name)} for name in ("paraphrase_unknown_words", "paraphrase_front_phrases"))
    for change in ({"paraphrase_probability": 0.25}, {"paraphrase_seed": 1}, *toggles):
        keys = _keys(dataclasses.replace(on, talar=dataclasses.replace(on.talar, **change)))
        assert keys["talar/translator"] != reference["talar/translator"], change
        assert keys["talar/task_language"] == reference["talar/task_language"], change
        off = dataclasses.replace(base, talar=dataclasses.replace(base.talar, **change))
        assert _keys(off)["talar/translator"] == _keys(base)["talar/translator"], change  # not read without paraphrases


@pytest.mark.parametrize("env", ["clevr", "kitchen"])
def test_the_token_readout_reruns_every_translator_and_no_nl_encoding_baseline(env):
    """``talar.translator_tokens`` is what translators read: TALAR's, Handcrafted's and GLA's translators and the
    end-to-end stage rerun; the game, GLA's auto-encoder and the BERT-* encodings (sentence readout) do not (every
    IFP key hashes the whole config, so the policies rerun regardless)."""

    def keys(method, tokens):
        config = default_config(env, method=method, physics="c")
        return _keys(dataclasses.replace(config, talar=dataclasses.replace(config.talar, translator_tokens=tokens)))

    rerun = {"talar/translator", "handcrafted/translator", "gla/translator", "end-to-end/joint"}
    for method in method_names():
        off, on = keys(method, False), keys(method, True)
        for stage in off:
            if stage != "ifp":
                assert (off[stage] != on[stage]) == (stage in rerun), f"{method}: {stage}"


def test_bert_encoding_size_reaches_the_ifp_key():
    """The defect this file guards: BERT-binary's encoding size comes from --talar.spec, which its key missed."""
    base = default_config("clevr", method="bert-binary", physics="c")
    wider = dataclasses.replace(base, talar=dataclasses.replace(base.talar, spec=TaskLanguageSpec(num_predicates=8)))
    assert _keys(base)["bert-binary"] != _keys(wider)["bert-binary"]
    assert _keys(base)["ifp"] != _keys(wider)["ifp"]
    # ... and an RG-only setting, which BERT-binary does not read, leaves its encoding key alone
    hotter = dataclasses.replace(base, talar=dataclasses.replace(base.talar, gumbel_temperature=8.0))
    assert _keys(base)["bert-binary"] == _keys(hotter)["bert-binary"]


def test_editing_an_env_model_reruns_the_oracle_and_the_policy(monkeypatch, tmp_path):
    import envs
    from experiments.pipeline import stage_oracle_key

    config = resolve(default_config("kitchen", physics="c", out=tmp_path))
    reference = (stage_oracle_key(config), stage_keys(config, UPSTREAM, CACHE)["ifp"])
    monkeypatch.setattr(envs, "model_fingerprint", lambda name: "an-edited-model")
    assert stage_oracle_key(config) != reference[0]
    assert stage_keys(config, UPSTREAM, CACHE)["ifp"] != reference[1]


def test_behaviour_cloning_keeps_its_budget_when_a_recipe_pins_it_and_the_translator_changes():
    base = default_config("clevr", method="pretrained-bert-binary", physics="c")
    bc = "pretrained-bert-binary/behaviour_cloning"

    def with_talar(config, **change):
        return dataclasses.replace(config, talar=dataclasses.replace(config.talar, **change))

    unpinned = with_talar(base, behaviour_cloning_steps=None, behaviour_cloning_learning_rate=None)
    # unpinned, behaviour cloning reads the translator's budget ...
    assert _keys(with_talar(unpinned, translator_steps=123))[bc] != _keys(unpinned)[bc]
    assert _keys(with_talar(unpinned, translator_learning_rate=0.01))[bc] != _keys(unpinned)[bc]
    # ... pinned to the same values it is the same stage, and a translator change no longer reaches it
    pinned = with_talar(
        unpinned,
        behaviour_cloning_steps=unpinned.talar.translator_steps,
        behaviour_cloning_learning_rate=unpinned.talar.translator_learning_rate,
    )
    assert _keys(pinned)[bc] == _keys(unpinned)[bc]
    assert _keys(with_talar(pinned, translator_steps=123, translator_learning_rate=0.01))[bc] == _keys(pinned)[bc]
    assert _keys(with_talar(pinned, behaviour_cloning_steps=123))[bc] != _keys(pinned)[bc]


def test_the_finetuned_bert_layers_reach_only_the_finetuned_baselines():
    """``talar.finetuned_bert_first_layer`` is read by the fine-tuned BERT-* encodings alone."""
    for method in method_names():
        base = default_config("kitchen", method=method, physics="c")
        top = dataclasses.replace(base, talar=dataclasses.replace(base.talar, finetuned_bert_first_layer=5))
        for stage, key in _keys(base).items():
            if stage != "ifp":
                assert (key != _keys(top)[stage]) == method.startswith("finetuned-"), f"{method}: {stage}"


def test_a_study_setting_equal_to_the_recipe_has_the_recipe_runs_keys():
    """The ablation's Table 2 setting and the dataset-size study's recipe size are the env command's run: same keys
    (oracle included), so ``--reuse-stages runs/kitchen`` copies them instead of training them again."""
    from experiments.pipeline import stage_oracle_key
    from experiments.study import StudyArgs, settings

    base = dataclasses.replace(default_config("kitchen", physics="c"), out=None)
    reference = resolve(base)
    expected = (stage_oracle_key(reference), _keys(base))
    ablation = settings(StudyArgs("ablation", experiment=base))
    sizes = settings(StudyArgs("dataset-size", experiment=base))
    for setting in (ablation["npn4-na2"], sizes["tuples50000"]):
        assert (stage_oracle_key(setting), stage_keys(setting, UPSTREAM, CACHE)) == expected
    for setting in (ablation["npn6-na4"], sizes["tuples10000"]):
        assert stage_keys(setting, UPSTREAM, CACHE)["ifp"] != expected[1]["ifp"]
    assert stage_oracle_key(sizes["tuples10000"]) != expected[0]


def test_nine_patterns_are_the_full_training_set_and_the_same_run():
    """Table 3's 9-pattern column is the compare command's run (same keys and folder), 5 patterns another."""
    from experiments.config import run_name

    base = default_config("clevr", physics="c")
    nine, five = resolve(dataclasses.replace(base, num_patterns=9)), resolve(dataclasses.replace(base, num_patterns=5))
    assert (nine.num_patterns, run_name(nine)) == (None, "talar") and run_name(five) == "talar-patterns5"
    assert _keys(dataclasses.replace(base, num_patterns=9)) == _keys(base)
    assert _keys(dataclasses.replace(base, num_patterns=5))["ifp"] != _keys(base)["ifp"]


def test_resolving_a_quick_config_again_keeps_a_smaller_budget():
    """Commands resolve, then set --ifp-env-steps, then ``run`` resolves again: the budget must survive."""
    config = resolve(default_config("clevr", physics="c", quick=True))
    assert config.ifp.total_env_steps == 10_240
    smaller = dataclasses.replace(config, ifp=dataclasses.replace(config.ifp, total_env_steps=512))
    assert resolve(smaller).ifp.total_env_steps == 512 and resolve(resolve(smaller)) == resolve(smaller)
