"""Impedance limits of the thesis (chapter 4, Appendix D): the Type 1 threshold of the linear
model with delay (`linear`), the Type 2 step test on the compliant, quantized axis (`steptest`),
thresholds from maps and edge searches (`search`), the analyses (`analysis`, `sensitivity`) and
their figures (`figures`). Sweeps run through `manus.experiments.stability.sweep` (vmapped, or on Dask)."""
