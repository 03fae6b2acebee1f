"""Residual diagnosis: tests on the calibrated model's residuals, the effects library (one module
per effect), stepwise selection and cross-run prediction. May import: core, frontend."""
