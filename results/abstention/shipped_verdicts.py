"""Verdict figures of the shipped agents on whole sentence sets (translation only, no episodes)."""
import json, sys
import numpy as np
from talar_jax import runtime
runtime.configure()
from talar_jax.agent import load
from talar_jax.language import DEVELOPMENT_FILE, load_instructions, load_user_instructions

out = {}
for name in ("kitchen", "clevr"):
    agent = load(name)
    sets = {}
    for split in ("train", "test"):
        ins = load_instructions(name, split)
        sets[split] = (list(ins.sentences), np.asarray(ins.goal_ids))
    dev_s, dev_g = load_user_instructions(DEVELOPMENT_FILE, name)
    sets["development"] = (list(dev_s), np.asarray(dev_g))
    data = json.load(open("talar_jax/language/data/abstention.json"))[name]
    sets["no goal"] = ([s for group in data["no_goal"].values() for s in group], None)
    sets["ambiguous"] = ([a["sentence"] for a in data["ambiguous"]], None)
    sets["opposite (near miss)"] = (list(data["near_miss"]), None)
    rows = {}
    for set_name, (sentences, goals) in sets.items():
        verdicts = agent.judge(sentences)
        acted = np.array([v.acts for v in verdicts])
        row = {"sentences": len(sentences), "acted_on_%": round(100 * acted.mean(), 1)}
        if goals is not None:
            right = np.array([v.goal == g for v, g in zip(verdicts, goals)])
            row["right_among_acted_%"] = round(100 * right[acted].mean(), 1) if acted.any() else None
        rows[set_name] = row
    out[name] = rows
    print(name, json.dumps(rows, indent=1))
json.dump(out, open(sys.argv[1], "w"), indent=2)
