"""Sparse-view techniques, one module each, behind gsgs_engine.train.technique.Technique."""
