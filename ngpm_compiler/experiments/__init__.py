"""Experiments: the evaluation of guided against unguided SMC, plots and reports."""
