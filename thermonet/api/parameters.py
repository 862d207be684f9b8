"""A fitted model's parameters in physical units, with standard errors (``est.parameters_``):
:mod:`thermonet.training.parameters` (its block bootstrap:
:mod:`thermonet.training.block_bootstrap`), where ``compare`` computes them too (and seals them
into every checkpoint it writes), re-exported here as the API has always named it."""

from ..training.block_bootstrap import (
    N_BOOTSTRAP,
    STDERR_METHODS,
    block_bootstrap_cov,
    block_length,
)
from ..training.parameters import (
    COLUMNS,
    FIXED,
    NEAR_ZERO,
    NO_SE,
    parameter_table,
    polynomial_coefficients,
    sealed_parameters,
    with_sealed,
)

__all__ = ["parameter_table", "polynomial_coefficients", "block_bootstrap_cov", "block_length",
           "sealed_parameters", "with_sealed", "COLUMNS", "FIXED", "NO_SE", "STDERR_METHODS",
           "N_BOOTSTRAP", "NEAR_ZERO"]
