"""Reconstruct each seed's evaluation goals from the eval keys, then per-seed x per-goal successes (bounds via LP)."""
import glob, json, sys
from pathlib import Path
import numpy as np
import jax, jax.numpy as jnp
from scipy.optimize import linprog
sys.path.insert(0, '.')
from envs.kitchen import tasks

def eval_goals(seed, num_seeds, index, E):
    root = jax.random.PRNGKey(seed + 1_000_003)
    keys = jax.random.split(jax.random.fold_in(root, index), num_seeds)
    out = []
    dist = tasks.task_distances(jnp.asarray(tasks.INIT_OBS))
    for k in keys:
        rng_reset, _ = jax.random.split(k)
        ep = jax.random.split(rng_reset, E)
        def g(key):
            rng_env = jax.random.split(key, 3)[0]
            rr = jax.random.split(rng_env)[1]
            rng_goal = jax.random.split(rr, 3)[0]
            return tasks.sample_goal(rng_goal, dist)
        out.append(np.asarray(jax.vmap(g)(ep)))
    return np.stack(out)  # (S, E)

def bounds(n, seed_succ, goal_succ, goal=0):
    """min/max of x[s, goal] over integer x with 0<=x<=n, row sums seed_succ, col sums goal_succ (LP, integral)."""
    S, G = n.shape
    A, b = [], []
    for s in range(S):
        row = np.zeros((S, G)); row[s] = 1; A.append(row.ravel()); b.append(seed_succ[s])
    for g in range(G):
        col = np.zeros((S, G)); col[:, g] = 1; A.append(col.ravel()); b.append(goal_succ[g])
    bnds = [(0, n[s, g]) for s in range(S) for g in range(G)]
    lo, hi = [], []
    for s in range(S):
        c = np.zeros((S, G)); c[s, goal] = 1; c = c.ravel()
        r1 = linprog(c, A_eq=A, b_eq=b, bounds=bnds); r2 = linprog(-c, A_eq=A, b_eq=b, bounds=bnds)
        if not r1.success: return None
        lo.append(round(r1.fun)); hi.append(round(-r2.fun))
    return lo, hi

if __name__ == '__main__':
    files = sys.argv[1:]
    cache = {}
    summary = {}
    for f in files:
        rows = [json.loads(l) for l in open(f)]
        S = len(rows[-1]['eval/train/success_per_seed'])
        res = []
        bad = 0
        for r in rows:
            if 'eval/train/success_per_seed' not in r: continue
            idx = r['step'] - 1
            key = (S, idx)
            if key not in cache: cache[key] = eval_goals(0, S, idx, 80)
            goals = cache[key]
            n = np.stack([np.bincount(goals[s], minlength=6) for s in range(S)])
            ncol = n.sum(0)
            gs = np.array([0 if v is None else v for v in r['eval/train/success_per_goal']]) * ncol
            ss = np.array(r['eval/train/success_per_seed']) * 80
            if np.abs(gs - np.round(gs)).max() > 1e-6 or np.abs(ss - np.round(ss)).max() > 1e-6 or round(gs.sum()) != round(ss.sum()):
                bad += 1
            b = bounds(n, np.round(ss), np.round(gs))
            res.append(dict(steps=r['train/env_steps'], n_mw=n[:, 0].tolist(), mw_bounds=b, seed=r['eval/train/success_per_seed'], goal=r['eval/train/success_per_goal']))
        summary[f] = res
        print(f, 'evals', len(res), 'inconsistent', bad)
    Path('runs/kitchen-seeds').mkdir(parents=True, exist_ok=True)
    json.dump(summary, open('runs/kitchen-seeds/perseed.json', 'w'))
