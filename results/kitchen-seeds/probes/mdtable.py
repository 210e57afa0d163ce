"""Markdown table of a probe run's evaluations: python mdtable.py <name> ... (runs/kitchen-seeds/<name>)."""
import json, sys
for name in sys.argv[1:]:
    rows = [json.loads(l) for l in open(f'runs/kitchen-seeds/{name}/metrics.jsonl')]
    print(f'\n{name}\n\n| env steps per seed | policy std | microwave success per seed (%) | eval return per seed |\n|---|---|---|---|')
    for r in rows:
        if 'eval/train/success_per_seed' in r:
            print(f"| {r['train/env_steps']:,} | {r['policy/std']:.2f} | {' / '.join(str(round(x*100)) for x in r['eval/train/success_per_seed'])} | {' / '.join(f'{x:+.2f}' for x in r['eval/train/episode_return_per_seed'])} |")
