"""Experiments built on the library: the calibration set of `manus diagnose` (`calibration`, its
hidden effects sized by `sizing`, its verdicts judged by `judging`) and a second simulator written
from the equations (`independent`); simulated recordings (`simulated`); free runs of fitted models
(`freerun`); parameter-convergence trials (`convergence`); the system identification of the
thesis (`sysid`) and its impedance limits (`stability`). The `manus` command (`manus.runs`) wires
them to the command line; nothing here imports it."""
