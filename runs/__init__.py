"""Experiments and the `manus` command: they wire plants, estimators and adaptive together."""
