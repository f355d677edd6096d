"""hsa_core: ROS-free model, planning, control and estimation for planar HSA robots.

Importing this package sets no global state: an entry point that computes with the model calls
:func:`hsa_core.jaxsetup.configure_jax` first (float64, dispatch, compilation cache); the model's
loader refuses to run without it.
"""

__version__ = "0.1.0"
