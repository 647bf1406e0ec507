"""Identification: a recording -> a model's parameters, in one direction.

Modules, each importing only those before it: `prepare` (a recording made ready: band,
kinematics, rows), `columns` (the effects' regressor columns on it, computed once), `lsq` (the
least-squares core: per-segment statistics, held-out folds, robust standard deviations, bounded
coefficients), `search` (an effect's non-linear parameter over its space), `result` (the fitted
result, `Fit`), `instruments` (IDIM-IV), `fit` (the entry point: a model fitted by LS or IV),
`consistency` (a serial chain's physically consistent parameters, a stage after the fit).
"""
