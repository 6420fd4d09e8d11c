"""Training: Gaussian model optimisation, densification, checkpoints, evaluation."""
