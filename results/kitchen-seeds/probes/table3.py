"""The per-seed microwave table of the recorded runs (after perseed.py)."""
import json, numpy as np
d = json.load(open('runs/kitchen-seeds/perseed.json'))
rows = []
allfirst = []; never = 0; total = 0; undetermined = 0
perseed_fail = np.zeros(5, int); perseed_n = np.zeros(5, int)
print('| run | other five sub-tasks, pooled (%) | microwave per seed, last 3 evals (successes lo-hi / episodes) | status per seed | microwave >= 50 % first at (per seed) |')
print('|---|---|---|---|---|')
for f, res in d.items():
    if len(res) < 49: continue
    name = f.split('results/')[1].replace('/ifp_metrics.jsonl', '')
    last = res[-3:]
    pooled = np.mean([[x for x in r['goal']] for r in last], 0)
    other = pooled[1:].min() * 100
    cells, status, first = [], [], []
    for s in range(5):
        lo = sum(r['mw_bounds'][0][s] for r in last); hi = sum(r['mw_bounds'][1][s] for r in last); n = sum(r['n_mw'][s] for r in last)
        cells.append(f'{lo}-{hi}/{n}' if lo != hi else f'{lo}/{n}')
        st = 'F' if hi / n < 0.5 else ('ok' if lo / n >= 0.8 else '?')
        status.append(st)
        fs = next((r['steps'] for r in res if r['n_mw'][s] and r['mw_bounds'][0][s] / r['n_mw'][s] >= 0.5), None)
        first.append('never' if fs is None else f'{fs/1e6:.2f}M')
        if other >= 90:
            total += 1
            if st == 'F': never += 1; perseed_fail[s] += 1
            if st == '?': undetermined += 1
            if st != '?': perseed_n[s] += 1
            if fs is not None and st == 'ok': allfirst.append(fs)
    print(f'| {name} | {other:.0f} (min) | {" ".join(cells)} | {" ".join(status)} | {" ".join(first)} |')
print()
print('runs whose other five sub-tasks are all >= 90 % pooled: seed-runs', total, 'never (F)', never, 'undetermined', undetermined)
print('fail per seed index', perseed_fail.tolist(), 'of determined', perseed_n.tolist())
a = np.array(allfirst) / 1e6
q = np.percentile(a, [25, 75]); print('learned seeds: first >=50%% at median %.2fM, quartiles %.2f %.2f, max %.2f, n %d' % (np.median(a), q[0], q[1], a.max(), len(a)))
