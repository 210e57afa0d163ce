"""A trained run as an agent: load, encode (= the cache), translate a new sentence, act, and the two commands."""

import json
import shutil

import jax
import numpy as np
import orbax.checkpoint as ocp
import pytest

from experiments import generalize, instruct
from experiments.reports import trained_codes
from talar_jax import encodings
from talar_jax.agent import Agent, AgentError, load, read_policy_params
from talar_jax.baselines import AlignedEncodingLayer
from talar_jax.checkpoint import save_tree
from talar_jax.encodings import ENCODING_FILE, EncodingArtifact, EncodingError, ParamsSource, register_encoding_kind
from talar_jax.language import TOKEN_READOUT, load_user_instructions, readout_features
from talar_jax.task_language import TaskLanguageSpec
from tests.helpers import one_line_error as _error


def talar_encoding(config: dict) -> EncodingArtifact:
    """The encoding record of a TALAR run of ``config`` (its translator, in ``talar/translator``)."""
    talar = config["talar"]
    readout = TOKEN_READOUT if talar.get("translator_tokens", False) else config["sentence_readout"]
    spec = TaskLanguageSpec(**talar["spec"])
    return EncodingArtifact.translator(
        spec, tuple(talar["translator_hidden"]), readout, "talar/translator/params.msgpack"
    )


@pytest.fixture(scope="module")
def talar_run(clevr_run):
    """The TALAR fixture run with its encoding record (written here, as the pipeline writes it, when missing)."""
    out, summary = clevr_run
    if not (out / "talar" / ENCODING_FILE).is_file():
        talar_encoding(json.loads((out / "talar" / "config.json").read_text())).write(out / "talar")
    return out, summary


def _finished_run(folder, config, method):
    """A method folder whose ifp stage is finished, with ``config`` naming ``method``."""
    (folder / "ifp").mkdir(parents=True)
    (folder / "ifp" / "stage.json").write_text("{}")
    (folder / "config.json").write_text(json.dumps({**config, "method": method}))


def _save_policy(out, folder, conditioner=None):
    """The TALAR fixture's seed-stacked policy in ``folder``'s checkpoint (with a ``conditioner`` entry if given)."""
    policy = {k: v for k, v in read_policy_params(out / "talar").items() if k != "conditioner"}
    extra = {} if conditioner is None else {"conditioner": conditioner}
    with ocp.CheckpointManager((folder / "ifp" / "ppo" / "checkpoints").absolute()) as manager:
        manager.save(7, args=ocp.args.StandardSave({"params": {**policy, **extra}}))
        manager.wait_until_finished()


@pytest.fixture(scope="module")
def agent(talar_run):
    out, _ = talar_run
    return load(out, seed=1)


def test_encoding_records_round_trip_through_json():
    spec = TaskLanguageSpec(num_predicates=4, num_arguments=2, arg_size=5)
    translator = EncodingArtifact.translator(
        spec, (256, 256), "tokens", "end-to-end/joint/params.msgpack", "translator"
    )
    assert translator.to_json() == {
        "kind": "translator",
        "readout": "tokens",
        "code_size": 14,
        "spec": {"num_predicates": 4, "num_arguments": 2, "arg_size": 5},
        "hidden": [256, 256],
        "binary": True,
        "continuous": False,
        "params": {"source": "file", "path": "end-to-end/joint/params.msgpack", "entry": "translator"},
        "unreadable_reason": None,
    }
    records = [
        translator,
        EncodingArtifact.nl_encoding_layer(14, binary=False, readout="sentence"),
        EncodingArtifact.aligned_encoding_layer(spec, (128, 128), binary=True, readout="sentence+prefixes"),
        EncodingArtifact.unreadable("a One-hot run has a code per training instruction", readout="sentence"),
    ]
    for record in records:
        assert EncodingArtifact.from_json(json.loads(json.dumps(record.to_json()))) == record
    layer = records[1].to_json()
    assert (
        layer["continuous"] and not layer["binary"] and layer["params"] == {"source": "policy", "entry": "conditioner"}
    )
    assert records[3].to_json()["params"] is None and not records[3].readable
    with pytest.raises(EncodingError, match="unknown keys"):
        EncodingArtifact.from_json({**translator.to_json(), "method": "talar"})
    with pytest.raises(EncodingError, match="unknown readout"):
        EncodingArtifact.from_json({**translator.to_json(), "readout": "words"})
    with pytest.raises(EncodingError, match="code_size 13 is not the size 14"):
        EncodingArtifact.from_json({**translator.to_json(), "code_size": 13})
    with pytest.raises(EncodingError, match="relative to the run root"):
        ParamsSource.file("/abs/params.msgpack")
    with pytest.raises(EncodingError, match="needs an unreadable_reason"):
        EncodingArtifact("none", "sentence", 0)


def test_agent_reads_sentences_as_the_run_did_and_acts(agent, talar_run):
    out, _ = talar_run
    assert agent.method == "talar" and agent.folder == out / "talar" and agent.seed == 1
    assert agent.encoding == talar_encoding(agent.config) and not agent.continuous_codes
    # The features of cached sentences are the cache's (train and test rows), and so are their codes.
    rows = [0, 5, 719, 720, 1439]
    sentences = [agent.cache.sentences[r] for r in rows]
    np.testing.assert_array_equal(agent.encode(sentences), agent.cache_features()[rows])
    tables = np.load(out / "talar" / "translator" / "tables.npy")
    np.testing.assert_array_equal(agent.translate(sentences), tables[1, rows])
    # A sentence no one trained on: a valid TL (4 predicate bits, two one-hot arguments).
    code = agent.translate("Could you please push the red ball so it ends up left of the blue one?")
    assert code.shape == (1, 14) and set(np.unique(code)) <= {0.0, 1.0}
    np.testing.assert_array_equal(code[0, 4:].reshape(2, 5).sum(-1), 1)
    # A code decodes to the goal most training instructions with that code have (here from the saved table).
    train = np.flatnonzero(agent.cache.is_train)
    same = train[np.all(tables[1, train] == tables[1, 0], axis=1)]
    counts = np.bincount(agent.cache.goal_ids[same], minlength=agent.cache.num_goals)
    assert counts[agent.nearest_goal(tables[1, 0])] == counts.max()
    assert agent.nearest_goal(1.0 - tables[1, 0]) in (None, *range(agent.cache.num_goals))
    goal = int(agent.cache.goal_ids[0])
    action = agent.act(np.zeros(agent.env.observation_size), code[0], jax.random.key(0), deterministic=True)
    assert action.shape == () and 0 <= int(action) < agent.env.action_spec.size
    episode = agent.rollout(sentences[0], jax.random.key(1), goal=goal)
    length = agent.env.episode_length
    assert episode.observations.shape == (length, agent.env.observation_size)
    assert episode.qpos.shape == (length + 1, agent.env.mj_model.nq)
    assert 1 <= episode.length <= length and episode.goal == goal
    assert episode.valid[: episode.length].all() and not episode.valid[episode.length :].any()
    # Batched episodes: one per (code, goal) row, the same successes as success_rate with the same key.
    codes, goals = agent.translate(sentences[:2]), np.array([goal, goal])
    observations, valid, success = agent.episodes(codes, goals, jax.random.key(2))
    assert observations.shape == (2, length, agent.env.observation_size) and valid.shape == (2, length)
    np.testing.assert_array_equal(success, agent.success_rate(codes, goals, jax.random.key(2)))


def test_a_sentence_that_is_not_a_string_is_a_one_line_type_error(agent):
    for bad, kind in ((123, "int"), (None, "NoneType"), (b"Open the door", "bytes")):
        with pytest.raises(TypeError, match=f"understand takes one sentence, a str; got {kind}") as error:
            agent.understand(bad)
        assert "\n" not in str(error.value)
    with pytest.raises(TypeError, match="a sentence is a str, got int: 7"):
        agent.judge(["Push the red ball", 7])
    with pytest.raises(TypeError, match="sentences are a str or a sequence of them, got int"):
        agent.translate(123)


def test_an_aligned_run_reads_sentences_through_its_generator_shaped_layer(agent, talar_run, tmp_path):
    """An aligned BERT-binary run (Fig. 12): the agent rebuilds the TL generator's networks from the run's encoding
    record and reads the seed's encoding layer from the policy checkpoint. The run here is the TALAR fixture's policy
    with an aligned layer of known parameters (seed-stacked as training stores them) put in its checkpoint."""
    out, _ = talar_run
    config = json.loads((out / "talar" / "config.json").read_text())
    folder = tmp_path / "aligned" / "aligned-bert-binary"
    _finished_run(folder, config, "aligned-bert-binary")
    spec = TaskLanguageSpec(**config["talar"]["spec"])
    hidden = tuple(config["talar"]["generator_hidden"])
    EncodingArtifact.aligned_encoding_layer(spec, hidden, binary=True, readout=config["sentence_readout"]).write(folder)
    layer = AlignedEncodingLayer(spec, hidden, binary=True)
    features = readout_features(agent.cache, config["sentence_readout"], agent.encoder)
    keys = jax.random.split(jax.random.key(3), config["seeds"])
    stacked = jax.vmap(lambda key: layer.init(key, features[:1]))(keys)
    _save_policy(out, folder, conditioner=stacked)
    aligned = Agent(folder, seed=1)
    assert not aligned.continuous_codes and "conditioner" not in aligned._policy_params
    expected = np.asarray(layer.apply(jax.tree.map(lambda x: x[1], stacked), features, None))
    rows = [0, 5, 719, 720, 1439]
    np.testing.assert_allclose(aligned.translate([aligned.cache.sentences[r] for r in rows]), expected[rows], atol=1e-6)
    np.testing.assert_allclose(trained_codes(folder, seed=1), expected, atol=1e-6)
    # A TL-shaped code: 0/1 predicates and one-hot arguments, as the generator's.
    assert set(np.unique(expected)) <= {0.0, 1.0}
    np.testing.assert_array_equal(
        expected[:, spec.num_predicates :].reshape(-1, spec.num_arguments, spec.arg_size).sum(-1), 1
    )
    episode = aligned.rollout(aligned.cache.sentences[0], jax.random.key(1), goal=int(aligned.cache.goal_ids[0]))
    assert 1 <= episode.length <= aligned.env.episode_length


def test_instruct_prints_the_code_and_success_and_writes_a_video(talar_run, tmp_path, capsys):
    out, _ = talar_run
    video = tmp_path / "episode.gif"
    result = instruct.run_command(
        [
            *[str(out), "move the red ball left of the blue ball", "--episodes", "4", "--goal", "3"],
            *["--video", str(video), "--act-anyway"],  # the tiny BERT's run has no calibration: act whatever it says
        ]
    )
    printed = capsys.readouterr().out
    assert "code:" in printed and "given with --goal" in printed
    assert result["goal"] == 3 and 0.0 <= result["success"] <= 1.0
    if "video: not written" in printed:
        pytest.skip("no OpenGL backend on this machine: the evaluation ran, the video was skipped")
    assert video.stat().st_size > 0 and result["video"] == str(video)


def test_generalize_on_the_test_patterns_reproduces_the_tables_agreement(talar_run, tmp_path, capsys):
    out, _ = talar_run
    mine = tmp_path / "mine.json"
    mine.write_text(
        json.dumps(
            {
                "clevr_patterns": ["Get the {subject} ball {relation} the {object} ball please"],
                "kitchen": {"kettle": ["move the kettle"]},
            }
        )
    )
    result = generalize.run_command(
        [str(out), "--instructions", str(mine), "--episodes", "8", "--json", str(tmp_path / "r.json")]
    )
    assert json.loads((tmp_path / "r.json").read_text())["sentences"] == {"train": 720, "test": 720, "yours": 80}
    tables = np.load(out / "talar" / "translator" / "tables.npy")
    for seed, row in enumerate(result["per_seed"]):
        agent = Agent(out, seed=seed)
        test = np.flatnonzero(~agent.cache.is_train)
        expected = np.mean([np.array_equal(tables[seed, r], agent.goal_code(agent.cache.goal_ids[r])) for r in test])
        assert row["test"]["tl_agreement"] == pytest.approx(expected)
        assert all(0.0 <= row[name]["success"] <= 1.0 for name in ("train", "test", "yours"))
    assert "mean ± std" in capsys.readouterr().out


def test_bad_input_gets_one_line(talar_run, tmp_path, capsys):
    out, _ = talar_run
    assert "is empty" in _error(capsys, instruct.main, [str(out), "   "])
    assert "does not exist" in _error(capsys, instruct.main, [str(tmp_path / "nowhere"), "go"])
    assert ".gif or .mp4" in _error(capsys, instruct.main, [str(out), "go", "--video", str(tmp_path / "v.avi")])
    unfinished = tmp_path / "unfinished"
    (unfinished / "talar" / "ifp").mkdir(parents=True)
    shutil.copy(out / "talar" / "config.json", unfinished / "talar" / "config.json")
    assert "not finished" in _error(capsys, instruct.main, [str(unfinished), "go"])
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"clevr_patterns": ["move the {subject} ball"], "kitchen": {"fridge": ["open it"]}}))
    assert "placeholders" in _error(capsys, generalize.main, [str(out), "--instructions", str(bad)])
    with pytest.raises(ValueError, match="unknown kitchen sub-task 'fridge'"):
        load_user_instructions(bad, "kitchen")
    only_kitchen = tmp_path / "kitchen.json"
    only_kitchen.write_text(json.dumps({"kitchen": {"kettle": ["move the kettle"]}}))
    assert "no 'clevr_patterns'" in _error(capsys, generalize.main, [str(out), "--instructions", str(only_kitchen)])


def test_a_run_whose_record_says_it_cannot_read_sentences_raises_the_records_reason(talar_run, tmp_path, capsys):
    out, _ = talar_run
    config = json.loads((out / "talar" / "config.json").read_text())
    reasons = {
        "onehot": "a One-hot run gives every training sentence its own code and has no way to read a new sentence",
        "finetuned-bert-binary": "a fine-tuned BERT run's encoder is its own; the agent has no way to read it",
    }
    for method, reason in reasons.items():
        folder = tmp_path / method / method
        _finished_run(folder, config, method)
        EncodingArtifact.unreadable(reason, readout=config["sentence_readout"]).write(folder)
        with pytest.raises(AgentError) as error:
            Agent(folder)
        assert str(error.value) == reason
        assert reason in _error(capsys, instruct.main, [str(folder), "go"])
    assert trained_codes(tmp_path / "onehot" / "onehot") is None


def test_a_run_without_an_encoding_record_asks_to_rerun_its_command(talar_run, tmp_path):
    out, _ = talar_run
    old = tmp_path / "old" / "talar"
    _finished_run(old, json.loads((out / "talar" / "config.json").read_text()), "talar")
    with pytest.raises(AgentError, match="predates the encoding record .* rerun its command") as error:
        Agent(old)
    assert len(str(error.value).splitlines()) == 1
    (old / ENCODING_FILE).write_text(json.dumps({"kind": "translator"}))
    with pytest.raises(AgentError, match="missing keys code_size, readout"):
        Agent(old)


def test_an_encoding_kind_registered_outside_the_library_is_what_the_agent_uses(
    agent, talar_run, tmp_path, monkeypatch
):
    """A kind the library does not know (a sign probe on the sentence features, its seed-stacked weights in a file
    of the run root under an entry): the agent builds it through the registry and acts on its codes."""
    out, _ = talar_run
    monkeypatch.setattr(encodings, "_KINDS", dict(encodings._KINDS))  # the registration ends with the test
    config = json.loads((out / "talar" / "config.json").read_text())
    root = tmp_path / "probe-run"
    folder = root / "sign-probe"
    _finished_run(folder, config, "sign-probe")
    _save_policy(out, folder)
    features = readout_features(agent.cache, config["sentence_readout"], agent.encoder)
    weights = np.random.default_rng(0).normal(size=(config["seeds"], features.shape[-1], agent.code_size))
    (folder / "probe").mkdir()
    save_tree(folder / "probe" / "params.msgpack", {"probe": {"w": weights.astype(np.float32)}})
    record = EncodingArtifact(
        "sign-probe",
        config["sentence_readout"],
        agent.code_size,
        binary=True,
        params=ParamsSource.file("sign-probe/probe/params.msgpack", entry="probe"),
    )
    record.write(folder)
    assert EncodingArtifact.read(folder) == record
    with pytest.raises(AgentError, match="encoding kind 'sign-probe' is not registered"):
        Agent(folder, seed=1)
    built = []

    def build(artifact, params):
        built.append(artifact)
        return lambda x: (x @ params["w"] > 0).astype(np.float32)

    register_encoding_kind("sign-probe", build)
    with pytest.raises(ValueError, match="already registered"):
        register_encoding_kind("sign-probe", build)
    probe = Agent(root, seed=1)
    assert built == [record] and probe.folder == folder and probe.code_size == agent.code_size
    rows = [0, 5, 719, 720, 1439]
    expected = (features[rows] @ weights[1] > 0).astype(np.float32)
    np.testing.assert_allclose(probe.translate([probe.cache.sentences[r] for r in rows]), expected)
    np.testing.assert_allclose(trained_codes(folder, seed=1), (features @ weights[1] > 0).astype(np.float32))
    episode = probe.rollout(probe.cache.sentences[0], jax.random.key(1), goal=int(probe.cache.goal_ids[0]))
    assert 1 <= episode.length <= probe.env.episode_length
