"""Per-seed microwave successes of a run's evaluations (bounds, see perseed.py): python mixedseed.py
<metrics.jsonl> <eval episodes per seed>; the base seed is read from the config.json beside it."""
import sys, json, numpy as np
sys.path.insert(0, str(__import__('pathlib').Path(__file__).parent))
import perseed
f = sys.argv[1]; E = int(sys.argv[2])
from pathlib import Path
config = Path(f).parent / 'config.json'
base_seed = json.loads(config.read_text()).get('seed', 0) if config.exists() else 0
for r in map(json.loads, open(f)):
    if 'eval/train/success_per_seed' not in r: continue
    S = len(r['eval/train/success_per_seed'])
    goals = perseed.eval_goals(base_seed, S, r['step'] - 1, E)
    n = np.stack([np.bincount(goals[s], minlength=6) for s in range(S)])
    gs = np.array([0 if v is None else v for v in r['eval/train/success_per_goal']]) * n.sum(0)
    ss = np.array(r['eval/train/success_per_seed']) * E
    assert np.abs(gs - gs.round()).max() < 1e-6, 'inconsistent'
    b = perseed.bounds(n, np.round(ss), np.round(gs))
    print(f"{r['train/env_steps']:>8d} microwave per seed lo {b[0]} hi {b[1]} of {n[:,0].tolist()}; seed success {[round(x*100) for x in r['eval/train/success_per_seed']]}")
