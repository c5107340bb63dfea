"""Guided SMC: the sampler, site order, resampling, distributions, proposals, guide, likelihoods."""
