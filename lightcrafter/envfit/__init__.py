"""Source environment-map fitting for real-video pseudo-pairs (paper appendix).

Modules: :mod:`.model` (parameters, map head, TV, tonemapped L1: the objective both solvers share),
:mod:`.video` (observed frames, fitted frames and used pixels, input checks), :mod:`.tracing`
(R's environment transport sampled independently of the map, Dr.Jit), :mod:`.reference`
(R differentiated with Mitsuba AD every iteration), :mod:`.transport` + :mod:`.fast` (the same
objective on a sparse transport traced once), :mod:`.fit` (settings, optimisation loop,
checkpoints, outputs: :func:`~.fit.fit_envmap`), :mod:`.evaluate` (the true objective by R at high
sample count, SH comparison), :mod:`.synthetic` (problems with a known map).
"""

from .fit import FitResult, FitSettings, fit_envmap, optimize, prepare

__all__ = ["FitResult", "FitSettings", "fit_envmap", "optimize", "prepare"]
