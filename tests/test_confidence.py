"""Translation confidence and verdicts: the measures on synthetic translators, the verdicts of hand-made
calibrations, and the agent, ``experiments.instruct``, ``experiments.generalize`` and ``experiments.calibrate`` on the
quick CLEVR run."""

import io
import json
import shutil

import jax
import numpy as np
import pytest

from experiments import calibrate, generalize, instruct
from talar_jax import agent as agent_module
from talar_jax.agent import CONFIDENCE_FILE, AgentError, default_calibration, read_calibration, read_encoding_params
from talar_jax.checkpoint import save_tree, write_json_atomic
from talar_jax.confidence import (
    AMBIGUOUS,
    NOT_UNDERSTOOD,
    UNDERSTOOD,
    Calibration,
    ConfidenceError,
    Measures,
    Understanding,
    goal_posterior,
    pooled_embeddings,
)
from talar_jax.encodings import (
    ENCODING_FILE,
    EncodingArtifact,
    ParamsSource,
    make_encoding,
    register_encoding_kind,
)
from talar_jax.talar import translator_nll
from talar_jax.task_language import TaskLanguageSpec, Translator
from tests.helpers import one_line_error as _error

NAMES = ["microwave", "kettle", "light switch", "top burner", "bottom burner"]


def hand_made(**changes) -> Calibration:
    """Acts from familiarity 0.8 when the posterior of the goal is 0.7 or more; ambiguous from familiarity 0.5."""
    values = dict(
        temperature=1.0,
        ensemble=True,
        features=("familiarity", "goal_logit"),
        mean=(0.8, np.log(0.7 / 0.3)),
        scale=(0.01, 0.01),
        coef=(1.0, 1.0),
        intercept=0.0,
        act_threshold=0.5,
        familiar_threshold=0.5,
    )
    return Calibration(**{**values, **changes})


def measures(familiarity, posterior, decoded) -> Measures:
    """One seed's measures whose goal posterior at temperature 1 is ``posterior``."""
    with np.errstate(divide="ignore"):
        log_likelihood = np.log(np.asarray(posterior, np.float64))[None]
    return Measures(np.asarray(familiarity, np.float64), log_likelihood, np.asarray(decoded)[None])


# --- verdicts of a hand-made calibration ---------------------------------------------------------------------------
def test_clear_ambiguous_and_nonsense_sentences_get_their_verdicts():
    calibration = hand_made()
    sentences = ["Open the microwave door.", "Turn on the burner.", "Make me a sandwich.", "Open the door."]
    found = measures(
        familiarity=[0.95, 0.9, 0.2, 0.9],
        posterior=[
            [0.97, 0.01, 0.01, 0.005, 0.005],
            [0.0, 0.02, 0.0, 0.52, 0.46],
            [0.3, 0.1, 0.2, 0.2, 0.2],
            [0.9, 0.02, 0.04, 0.02, 0.02],
        ],
        decoded=[0, 3, 0, -1],  # the last sentence's code decodes to no goal: never acted on
    )
    clear, burner, sandwich, door = calibration.verdicts(found, 0, sentences)
    assert (clear.verdict, clear.goal, clear.decoded) == (UNDERSTOOD, 0, 0) and clear.acts
    assert clear.confidence > 0.99 and clear.candidates[0] == (0, pytest.approx(0.97))
    assert (burner.verdict, burner.goal) == (AMBIGUOUS, None) and not burner.acts
    assert [g for g, _ in burner.candidates] == [3, 4]  # the two likeliest, best first; the rest under the floor
    assert burner.confidence < 0.5
    assert (sandwich.verdict, sandwich.goal) == (NOT_UNDERSTOOD, None)
    assert (door.verdict, door.confidence, door.decoded) == (AMBIGUOUS, 0.0, None)
    assert "top burner (0.52) or bottom burner (0.46)" in burner.describe(NAMES)
    assert burner.describe(NAMES).startswith('not sure: "Turn on the burner." could be')
    assert sandwich.describe(NAMES).startswith('not understood: "Make me a sandwich."')
    assert "microwave" in clear.describe(NAMES) and "\n" not in burner.describe(NAMES)
    record = burner.to_json(NAMES)
    assert record["verdict"] == "ambiguous" and record["goal"] is None
    assert [c["name"] for c in record["candidates"]] == ["top burner", "bottom burner"]


def test_thresholds_decide_and_candidates_are_capped():
    found = measures([0.9], [[0.4, 0.3, 0.2, 0.06, 0.04]], [0])
    assert hand_made().verdicts(found, 0, ["x"])[0].verdict == AMBIGUOUS
    assert hand_made(act_threshold=0.0).verdicts(found, 0, ["x"])[0].verdict == UNDERSTOOD
    assert hand_made(familiar_threshold=0.95).verdicts(found, 0, ["x"])[0].verdict == NOT_UNDERSTOOD
    assert len(hand_made().verdicts(found, 0, ["x"])[0].candidates) == 3
    assert len(hand_made(max_candidates=2).verdicts(found, 0, ["x"])[0].candidates) == 2
    with pytest.raises(ConfidenceError, match="seed 1 is not among the 1 seeds"):
        hand_made().verdicts(found, 1, ["x"])


def test_calibrations_round_trip_and_bad_ones_give_one_line(tmp_path):
    calibration = hand_made(source={"run": "runs/kitchen/talar"})
    path = tmp_path / CONFIDENCE_FILE
    write_json_atomic(path, calibration.to_json())
    again = read_calibration(tmp_path)
    assert again == calibration and again.source == {"run": "runs/kitchen/talar"}
    assert default_calibration().source.get("default") is True
    with pytest.raises(ConfidenceError, match="unknown confidence features"):
        hand_made(features=("familiarity", "vibes"))
    data = json.loads(path.read_text())
    del data["act_threshold"]
    path.write_text(json.dumps(data))
    with pytest.raises(AgentError, match="missing keys act_threshold.*python -m experiments.calibrate"):
        read_calibration(path)
    path.write_text("{not json")
    with pytest.raises(AgentError, match="not valid JSON"):
        read_calibration(path)


def test_an_agent_holding_one_seed_uses_the_single_seed_calibration():
    single = hand_made(ensemble=False, act_threshold=0.9)
    ensemble = hand_made(single_seed=single)
    assert ensemble.for_seeds(5) is ensemble and ensemble.for_seeds(1) is single
    assert Calibration.from_json(json.loads(json.dumps(ensemble.to_json()))).single_seed == single
    with pytest.raises(ConfidenceError, match="holds one; calibrate it again"):
        hand_made().for_seeds(1)
    with pytest.raises(ConfidenceError, match="only an ensemble calibration holds a single-seed one"):
        hand_made(ensemble=False, single_seed=single)
    assert default_calibration().for_seeds(1).ensemble is False


def test_the_ensemble_spreads_the_posterior_when_seeds_disagree():
    log_likelihood = np.array([[[0.0, -20.0, -20.0]], [[-20.0, 0.0, -20.0]]])  # (K=2, S=1, G=3)
    found = Measures(np.ones(1), log_likelihood, np.array([[0], [1]]))
    alone, own = found.goal_posteriors(0, 1.0, ensemble=False)
    together, _ = found.goal_posteriors(0, 1.0, ensemble=True)
    assert alone[0, 0] == pytest.approx(1.0) and own is alone
    np.testing.assert_allclose(together[0], [0.5, 0.5, 0.0], atol=1e-6)
    assert hand_made(ensemble=True).confidence(found, 0)[0] < 0.5 < hand_made(ensemble=False).confidence(found, 0)[0]
    np.testing.assert_allclose(goal_posterior(np.array([0.0, -np.log(3.0)]), 1.0), [0.75, 0.25])


# --- measures of synthetic encodings -------------------------------------------------------------------------------
def _translator_run(tmp_path, spec, hidden=(16,), seeds=2, dim=8, readout="sentence"):
    """A method folder with a seed-stacked random translator and its record."""
    folder = tmp_path / "run" / "talar"
    folder.mkdir(parents=True)
    translator = Translator(spec, hidden)
    keys = jax.random.split(jax.random.key(0), seeds)
    params = jax.vmap(lambda k: translator.init(k, np.zeros((1, dim), np.float32)))(keys)
    save_tree(folder / "translator.msgpack", jax.device_get(params))
    artifact = EncodingArtifact.translator(spec, hidden, readout, "talar/translator.msgpack")
    return folder, artifact, translator, params


def test_goal_log_likelihoods_are_the_translators_eq3_likelihoods_and_codes_its_own(tmp_path):
    spec = TaskLanguageSpec(num_predicates=2, num_arguments=2, arg_size=3)
    folder, artifact, translator, params = _translator_run(tmp_path, spec)
    rng = np.random.default_rng(0)
    train = rng.normal(size=(30, 8)).astype(np.float32)
    goals = np.arange(30) % 3
    understanding = Understanding(artifact, read_encoding_params(folder, artifact), train, goals, 3)
    assert understanding.scored and understanding.num_seeds == 2
    queries = rng.normal(size=(5, 8)).astype(np.float32)
    log_likelihood = understanding.log_likelihoods(queries)  # (K, S, G)
    for seed in range(2):
        one = jax.tree.map(lambda x, s=seed: x[s], params)
        logits = translator.apply(one, queries)
        for goal in range(3):
            code = np.broadcast_to(understanding.goal_codes[seed, goal], (5, spec.size))
            np.testing.assert_allclose(
                log_likelihood[seed, :, goal], -np.asarray(translator_nll(spec, logits, code)), rtol=1e-5, atol=1e-4
            )
        np.testing.assert_array_equal(
            understanding.codes(queries)[seed], np.asarray(make_encoding(artifact, folder, seed)(queries))
        )
    # A training sentence is as familiar as can be; its pooled embedding is its own (normalised) vector.
    np.testing.assert_allclose(understanding.familiarity(train[:3]), 1.0, atol=1e-5)
    np.testing.assert_allclose(
        pooled_embeddings(train[:2], "sentence"), train[:2] / np.linalg.norm(train[:2], axis=1, keepdims=True)
    )


def test_token_states_pool_to_the_mean_of_their_real_tokens():
    states = np.zeros((1, 4, 3), np.float32)
    states[0, :2] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
    np.testing.assert_allclose(pooled_embeddings(states, "tokens")[0], [2**-0.5, 2**-0.5, 0.0], atol=1e-6)


def test_a_kind_without_a_scorer_is_judged_on_its_hard_codes(tmp_path):
    kind = "test-prototypes"

    def build(artifact, params):
        return lambda features: jax.nn.one_hot(np.argmax(features @ params["prototypes"].T, -1), 3)

    register_encoding_kind(kind, build, replace=True)
    folder = tmp_path / "run" / "proto"
    folder.mkdir(parents=True)
    prototypes = np.stack([np.eye(3, 4), np.eye(3, 4)[[1, 0, 2]]]).astype(np.float32)  # seed 1 swaps goals 0, 1
    save_tree(folder / "p.msgpack", {"prototypes": prototypes})
    artifact = EncodingArtifact(kind, "sentence", 3, binary=True, params=ParamsSource.file("proto/p.msgpack"))
    train = np.eye(3, 4, dtype=np.float32)
    understanding = Understanding(artifact, read_encoding_params(folder, artifact), train, np.arange(3), 3)
    assert not understanding.scored
    found = understanding.measure(np.eye(3, 4, dtype=np.float32)[:1])
    np.testing.assert_array_equal(found.decoded[:, 0], [0, 0])  # each seed decodes by its own training codes
    posterior, _ = found.goal_posteriors(0, 1.0, ensemble=True)
    assert posterior[0].argmax() == 0 and posterior[0, 0] > 0.99


# --- the agent and the commands on the quick CLEVR run --------------------------------------------------------------
ACT_ON_TRAINING_SENTENCES = dict(
    features=("familiarity",), mean=(0.99999,), scale=(0.000001,), coef=(1.0,), intercept=0.0, act_threshold=0.5
)
"""Acts on sentences as familiar as a training instruction, never on others (the tests' tiny BERT puts every sentence
of the CLEVR instruction set above 0.995 of a training one)."""


@pytest.fixture(scope="module")
def run_copy(clevr_run, tmp_path_factory):
    """A copy of the quick CLEVR run (its encoding record written) whose calibration the tests may change."""
    out, _ = clevr_run
    copy = tmp_path_factory.mktemp("confidence") / "clevr"
    shutil.copytree(out, copy)
    if not (copy / "talar" / ENCODING_FILE).is_file():
        from experiments.reports import write_encoding_record

        write_encoding_record(copy / "talar")
    return copy


def _calibrate_copy(run_copy, **changes):
    write_json_atomic(
        run_copy / "talar" / CONFIDENCE_FILE, hand_made(**{**ACT_ON_TRAINING_SENTENCES, **changes}).to_json()
    )


def test_the_agent_understands_its_training_sentences_and_not_others(run_copy):
    _calibrate_copy(run_copy, familiar_threshold=0.0)
    follower = agent_module.load(run_copy, seed=1)
    assert follower.calibrated and follower.calibration.features == ("familiarity",)
    sentence = follower.cache.sentences[0]
    verdict = follower.understand(sentence)
    assert verdict.verdict == UNDERSTOOD and verdict.familiarity == pytest.approx(1.0, abs=1e-4)
    assert verdict.decoded == follower.nearest_goal(follower.translate(sentence)[0]) == verdict.goal
    other = follower.understand("zzz qqq the the")
    assert other.verdict == AMBIGUOUS and other.goal is None and other.familiarity < 0.99999
    follower.calibration = hand_made(**ACT_ON_TRAINING_SENTENCES, familiar_threshold=1.5)
    assert follower.understand("zzz qqq the the").verdict == NOT_UNDERSTOOD
    # Verdicts of many sentences at once are those of one at a time.
    rows = [0, 5, 100]
    many = follower.judge([follower.cache.sentences[r] for r in rows])
    assert [v.decoded for v in many] == [follower.understand(follower.cache.sentences[r]).decoded for r in rows]


def _count_episodes(monkeypatch) -> list[int]:
    calls = []
    real = agent_module.Agent.episodes  # what success_rate and instruct run episodes through

    def counted(self, codes, goals, rng, deterministic=False):
        calls.append(len(goals))
        return real(self, codes, goals, rng, deterministic)

    monkeypatch.setattr(agent_module.Agent, "episodes", counted)
    return calls


def test_instruct_acts_on_what_it_understood_and_writes_the_json(run_copy, tmp_path, capsys, monkeypatch):
    _calibrate_copy(run_copy, familiar_threshold=0.0)
    calls = _count_episodes(monkeypatch)
    sentence = "Push the red ball in front of the blue ball."  # a training sentence of the CLEVR set
    out = tmp_path / "acted.json"
    result = instruct.run_command([str(run_copy), sentence, "--episodes", "3", "--json", str(out)])
    printed = capsys.readouterr().out
    assert "confidence: 1.00 (understood" in printed and "success: " in printed and calls == [3]
    written = json.loads(out.read_text())
    assert written == json.loads(json.dumps(result))
    for key in ("sentence", "code", "decoded_goal", "confidence", "verdict", "candidates", "success"):
        assert key in written, key
    assert written["verdict"] == "understood" and written["acted"] is True and 0.0 <= written["success"] <= 1.0


def test_instruct_abstains_in_one_line_and_runs_no_episode(run_copy, tmp_path, capsys, monkeypatch):
    _calibrate_copy(run_copy, familiar_threshold=0.0)
    calls = _count_episodes(monkeypatch)
    out = tmp_path / "abstained.json"
    result = instruct.run_command([str(run_copy), "zzz qqq the the", "--json", str(out)])
    lines = capsys.readouterr().out.strip().splitlines()
    assert calls == [] and not any(line.startswith("success") for line in lines)
    assert lines[-1].startswith('not sure: "zzz qqq the the" ') and lines[-1].endswith("rephrase, or --act-anyway")
    written = json.loads(out.read_text())
    assert written["verdict"] == "ambiguous" and written["acted"] is False and "success" not in written
    assert written == json.loads(json.dumps(result))
    result = instruct.run_command([str(run_copy), "zzz qqq the the", "--act-anyway", "--episodes", "2", "--goal", "4"])
    assert calls == [2] and result["acted"] is True and result["goal"] == 4
    assert "acting anyway (--act-anyway): the verdict was ambiguous" in capsys.readouterr().out


def test_instruct_reads_sentences_from_stdin_until_its_end(run_copy, tmp_path, capsys, monkeypatch):
    _calibrate_copy(run_copy, familiar_threshold=1.5)
    calls = _count_episodes(monkeypatch)
    sentences = "Push the red ball in front of the blue ball.\n\n   \nzzz qqq the the\n"
    monkeypatch.setattr("sys.stdin", io.StringIO(sentences))
    out = tmp_path / "session.json"
    results = instruct.run_command([str(run_copy), "--episodes", "2", "--json", str(out)])
    captured = capsys.readouterr()
    assert [r["verdict"] for r in results] == ["understood", "not understood"]
    assert calls == [2]  # one episode batch, for the sentence understood
    assert captured.err.strip().splitlines() == ["error: the sentence is empty"] * 2
    assert captured.out.count("run: ") == 1 and captured.out.count("sentence: ") == 2
    assert 'not understood: "zzz qqq the the"' in captured.out
    assert [r["sentence"] for r in json.loads(out.read_text())] == [r["sentence"] for r in results]


def test_bad_input_of_the_new_options_gets_one_line(run_copy, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr("sys.stdin", io.StringIO("go\n"))
    assert "does not exist" in _error(capsys, instruct.main, [str(tmp_path / "nowhere")])
    assert "--video needs a sentence" in _error(capsys, instruct.main, [str(run_copy), "--video", "v.gif"])
    (run_copy / "talar" / CONFIDENCE_FILE).write_text('{"temperature": 1}')
    assert "malformed calibration" in _error(capsys, instruct.main, [str(run_copy), "go"])
    assert "--sentence-episodes must be >= 0" in _error(
        capsys, generalize.main, [str(run_copy), "--instructions", "x.json", "--sentence-episodes", "-1"]
    )
    assert "does not exist" in _error(capsys, calibrate.main, [str(tmp_path / "nowhere")])
    assert "--reject-target must lie in" in _error(capsys, calibrate.main, [str(run_copy), "--reject-target", "2"])


def test_generalize_reports_verdicts_per_sentence_and_selective_figures(run_copy, tmp_path, capsys):
    _calibrate_copy(run_copy, familiar_threshold=0.0)
    mine = tmp_path / "mine.json"
    mine.write_text(json.dumps({"clevr_patterns": ["Push the {subject} ball {relation} the {object} ball."]}))
    markdown = tmp_path / "yours.md"
    result = generalize.run_command(
        [str(run_copy), "--instructions", str(mine), "--episodes", "4", "--markdown", str(markdown)]
    )
    assert result["calibrated"] is True
    for row in result["per_seed"]:
        assert row["train"]["coverage"] == 1.0 and row["yours"]["coverage"] == 1.0  # the training pattern itself
        assert 0.0 <= row["train"]["accuracy_acted"] <= 1.0 and row["test"]["coverage"] == 0.0
        assert row["test"]["accuracy_acted"] is None and row["test"]["verdicts"]["ambiguous"] == 720
    assert len(result["yours"]) == 80
    record = result["yours"][0]["per_seed"][1]
    for key in ("goal", "decoded_goal", "confidence", "verdict", "candidates", "success"):
        assert key in record, key
    assert record["verdict"] == "understood" and record["success"] in (0.0, 1.0)
    table = markdown.read_text()
    assert "| sentence | intended goal | decoded goal | confidence | verdict | success when acted |" in table
    assert "understood 2/2" in table and "coverage" in capsys.readouterr().out
    assert "| set | measure | target share |" in table
    for row in result["per_seed"]:
        for measure in generalize.RISK_MEASURES:
            curve = row["yours"]["risk_coverage"][measure]
            assert [r["target"] for r in curve] == list(generalize.COVERAGES)
            assert curve[0]["coverage"] == 1.0 and all(r["coverage"] <= 1.0 for r in curve)


def test_risk_coverage_acts_on_the_highest_scores_and_counts_the_wrong_among_them():
    scores = [0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2, 0.1, 0.95]
    actable = [True] * 9 + [False]  # the highest score has no goal to act on
    right = [True, True, False, True, True, False, True, True, True, True]
    rows = generalize.risk_coverage(scores, actable, right, (1.0, 0.5, 0.2, 0.0))
    assert rows[0] == {"target": 1.0, "threshold": 0.1, "coverage": 0.9, "risk": pytest.approx(2 / 9)}
    assert rows[1] == {"target": 0.5, "threshold": 0.5, "coverage": 0.5, "risk": pytest.approx(1 / 5)}
    assert rows[2] == {"target": 0.2, "threshold": 0.8, "coverage": 0.2, "risk": 0.0}
    assert rows[3] == {"target": 0.0, "threshold": None, "coverage": 0.0, "risk": None}
    tied = generalize.risk_coverage([0.5, 0.5, 0.5, 0.1], [True] * 4, [True, False, True, True], (0.25,))
    # every sentence at the threshold is acted on
    assert tied[0]["coverage"] == 0.75 and tied[0]["risk"] == pytest.approx(1 / 3)


def test_calibrate_fits_a_calibration_the_agent_then_uses(run_copy, tmp_path, capsys):
    data = tmp_path / "abstention.json"
    data.write_text(
        json.dumps(
            {
                "clevr": {
                    "no_goal": {"errands": ["Make me a sandwich.", "Wash the dishes.", "Feed the cat.", "hmm"]},
                    "near_miss": ["Push the yellow ball to the left of the red ball.", "Put the cube on the cone."],
                    "ambiguous": [
                        {"sentence": "Push the red ball.", "goals": {"subject": ["red"]}},
                        {"sentence": "Move the blue ball to the left.", "goals": {"subject": ["blue"]}},
                    ],
                }
            }
        )
    )
    out = tmp_path / "confidence.json"
    record = calibrate.run_command(
        [str(run_copy), "--data", str(data), "--out", str(out), "--json", str(tmp_path / "r.json")]
    )
    fitted = read_calibration(out)
    assert fitted.features == calibrate.STUDY[calibrate.CHOSEN][0] and fitted.ensemble
    assert fitted.source["env"] == "clevr" and fitted.source["sentences"]["no_goal"] == 4
    held = record["results"][calibrate.CHOSEN]["held_out"]
    assert set(held) == {"train", "test", "dev", "no_goal", "near_miss", "ambiguous"}
    assert held["ambiguous"]["sentences"] == 1 and "candidates_hold_a_meant_goal" in held["ambiguous"]
    printed = capsys.readouterr().out
    assert "measures compared" in printed and f"calibration: {out}" in printed
    curve = [
        line for line in printed.splitlines() if line.startswith(f"| {calibrate.CHOSEN} | ") and line.count("|") == 6
    ]
    assert len(curve) == 5 and curve[0].split("|")[2].strip() == "100.0"  # one row per target share, all first
    shutil.copy(out, run_copy / "talar" / CONFIDENCE_FILE)
    assert agent_module.load(run_copy).calibration == fitted


def test_the_halves_alternate_within_each_goal_and_pattern():
    from talar_jax.confidence.fit import by_pattern, group_halves

    assert group_halves([0, 0, 1, 0, 1]) == ["calibration", "held_out", "calibration", "calibration", "held_out"]
    assert by_pattern(6, 2) == ["calibration"] * 2 + ["held_out"] * 2 + ["calibration"] * 2
    names = [f"g{i}" for i in range(80)]
    assert len(calibrate.meant_goals("clevr", {"subject": ["red"]}, names)) == 16
    assert len(calibrate.meant_goals("clevr", {"subject": ["red"], "object": ["blue"]}, names)) == 4
    assert calibrate.meant_goals("kitchen", ["Kettle", "microwave"], NAMES) == (1, 0)
    with pytest.raises(ValueError, match="unknown goals"):
        calibrate.meant_goals("kitchen", ["fridge"], NAMES)


def test_the_act_threshold_keeps_the_coverage_target_before_asking_back_ambiguous_sentences():
    from talar_jax.confidence.fit import choose_act_threshold

    # one seed; four development sentences (confidence 0.9, 0.8, 0.35, 0.3), two ambiguous ones (0.4, 0.32) and two
    # no-goal ones (0.1, 0.05); every code decodes to its meant goal
    confidence = np.array([[0.9, 0.8, 0.35, 0.3, 0.4, 0.32, 0.1, 0.05]])
    sets = np.array(["dev"] * 4 + ["ambiguous"] * 2 + ["no_goal"] * 2)
    goals = np.array([0, 1, 2, 3, -1, -1, -1, -1])
    decoded = np.array([[0, 1, 2, 3, 0, 1, 2, 3]])
    rows = np.ones(8, bool)
    args = (confidence, decoded, sets, goals, rows, 0.95, 0.98)
    asked_back = choose_act_threshold(*args, ambiguous_weight=1.0)  # asking both back outweighs two dev sentences
    assert asked_back > 0.4
    covered = choose_act_threshold(*args, ambiguous_weight=1.0, coverage_target=1.0)
    assert covered == pytest.approx(0.3)  # every development sentence acted on, no-goal ones still not
    # a code that decodes to no goal is not the threshold's to mend: the target counts the sentences it decides
    missed = decoded.copy()
    missed[0, 3] = -1
    assert choose_act_threshold(confidence, missed, sets, goals, rows, 0.95, 0.98, 1.0, 1.0) == pytest.approx(0.35)
