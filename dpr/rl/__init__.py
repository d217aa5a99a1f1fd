"""Training: SB3 learners from scratch or from a clone, per-robot fine-tuning, resumable runs and their budgets."""
