"""Scoring: policies run over seeds with the paper's metrics, and what is read from the scores (evaluation files,
statistics, reports and figures, model cards, and the comparison of two recipes)."""
