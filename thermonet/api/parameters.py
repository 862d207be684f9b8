"""A fitted model's parameters in physical units, with standard errors (``est.parameters_``):
:mod:`thermonet.training.parameters`, where ``compare`` computes them too (and seals them into
every checkpoint it writes), re-exported here as the API has always named it."""

from ..training.parameters import (
    COLUMNS,
    FIXED,
    N_BOOTSTRAP,
    NEAR_ZERO,
    NO_SE,
    STDERR_METHODS,
    block_bootstrap_cov,
    block_length,
    parameter_table,
    polynomial_coefficients,
    sealed_parameters,
    with_sealed,
)

__all__ = ["parameter_table", "polynomial_coefficients", "block_bootstrap_cov", "block_length",
           "sealed_parameters", "with_sealed", "COLUMNS", "FIXED", "NO_SE", "STDERR_METHODS",
           "N_BOOTSTRAP", "NEAR_ZERO"]
