"""hsa_core: ROS-free model, planning, control and estimation for planar HSA robots.

Importing this package switches JAX to float64: the model needs double precision (model.md §9.1).
"""

import jax

jax.config.update("jax_enable_x64", True)

__version__ = "0.1.0"
