"""Measures on finished runs and records, each a command (``python -m experiments.analysis.<name> --help``).

- ``code_grouping``: how tightly a run's instruction codes group by goal, per seed (Fig. 12's aligned baselines);
- ``early_curves``: methods' learning curves up to a common env-step budget (a reduced-budget run against the first
  steps of full ones);
- ``finetuned_bert_drift``: how far a fine-tuned BERT run's encoder moved, and whether its embeddings still group by
  goal (Fig. 14);
- ``side_tasks``: whether a kitchen policy reaches its goal directly or by doing other sub-tasks on the way;
- ``translator_robustness``: translators with and without paraphrase augmentation on a run's referential game, by TL
  agreement (and success) on the training, test and development instructions;
- ``encoder_neighbours``: whether a sentence encoder puts each kitchen development phrasing next to its sub-task's
  training sentences (needs sentence-transformers, outside the project's environment).
"""
