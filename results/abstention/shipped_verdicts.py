"""Verdict figures of the shipped agents on whole sentence sets (translation only, no episodes).

``python results/abstention/shipped_verdicts.py OUT.json [SWAPS.json]``: besides the paper's and the project's sets,
the development phrasings' held-out half (the calibration's split) and the held-out half of the sentences naming
something the env does not have (``unknown_set``); ``SWAPS.json`` ({env: [sentences]}) gives those sentences instead,
for measuring a checkout that cannot build them."""
import json, sys
import numpy as np
from talar_jax import runtime
runtime.configure()
from talar_jax.agent import load
from talar_jax.confidence.fit import HELD_OUT, by_pattern, group_halves
from talar_jax.language import DEVELOPMENT_FILE, load_instructions, load_user_instructions

swaps = json.load(open(sys.argv[2])) if len(sys.argv) > 2 else None
out = {}
for name in ("kitchen", "clevr"):
    agent = load(name)
    sets = {}
    for split in ("train", "test"):
        ins = load_instructions(name, split)
        sets[split] = (list(ins.sentences), np.asarray(ins.goal_ids))
    dev_s, dev_g = load_user_instructions(DEVELOPMENT_FILE, name)
    sets["development"] = (list(dev_s), np.asarray(dev_g))
    parts = by_pattern(len(dev_s), agent.env.num_goals) if name == "clevr" else group_halves(list(dev_g))
    held = [i for i, part in enumerate(parts) if part == HELD_OUT]
    sets["development (held-out half)"] = ([dev_s[i] for i in held], np.asarray(dev_g)[held])
    data = json.load(open("talar_jax/language/data/abstention.json"))[name]
    sets["no goal"] = ([s for group in data["no_goal"].values() for s in group], None)
    sets["ambiguous"] = ([a["sentence"] for a in data["ambiguous"]], None)
    sets["opposite (near miss)"] = (list(data["near_miss"]), None)
    if swaps is None:
        from talar_jax.language.polarity import unknown_set

        swapped = list(unknown_set(name, agent.encoder.whole_words()).half(True).sentences)
    else:
        swapped = swaps[name]
    sets["names what it lacks (held-out swaps)"] = (swapped, None)
    rows = {}
    for set_name, (sentences, goals) in sets.items():
        verdicts = agent.judge(sentences)
        acted = np.array([v.acts for v in verdicts])
        row = {"sentences": len(sentences), "acted_on_%": round(100 * acted.mean(), 1)}
        if goals is not None:
            right = np.array([v.goal == g for v, g in zip(verdicts, goals)])
            row["right_among_acted_%"] = round(100 * right[acted].mean(), 1) if acted.any() else None
        rows[set_name] = row
    rows["near misses, verbatim"] = [
        {"sentence": v.sentence, "verdict": v.verdict, "goal": v.goal, "reason": v.reason}
        for v in agent.judge(list(data["near_miss"]))
    ]
    out[name] = rows
    print(name, json.dumps(rows, indent=1))
json.dump(out, open(sys.argv[1], "w"), indent=2)
