"""Evaluation: SMC runs of guides on target sets, their statistics and CSV files, held-out
scoring and its run cache (shared by `ngpmc eval`, `iterate` and `tune`)."""
