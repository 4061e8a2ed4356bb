"""The global least-squares problem of seed 003: parameters, residuals, priors, gauges and the compiled per-frame
functions."""
