"""Process-wide JAX configuration: cstiffjax always works in float64.

Near-taut catenaries and stiff cables (EA ~ 1e6 N on strains ~ 1e-4) lose all
their significant digits in float32, so the package enables ``jax_enable_x64``
as soon as it is imported.
"""

import jax

jax.config.update("jax_enable_x64", True)
