"""Trajectory evaluation as a library: ATE / RPE, alignment, reports. Plotting lives in `eval.plots`."""
