"""Learning and evaluation: scoring policies with the paper's metrics (SB3 training comes here too)."""
