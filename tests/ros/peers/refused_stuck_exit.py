"""A node under ``hsa_common.runner.run`` whose parameters are refused, in a process whose
interpreter teardown hangs (an exit handler that sleeps 60 s in C, as JAX/XLA's teardown can hang):
test_exit_deadline proves the refusal still ends the process at once with exit 2.
"""

import atexit
import ctypes
import sys

from hsa_common.parameters import ParameterValidationError
from hsa_common.runner import run


def refuse() -> None:
    """The node's construction: its parameters are refused."""
    raise ParameterValidationError("parameter 'max_iteration' is not a parameter of this node")


if __name__ == "__main__":
    atexit.register(ctypes.PyDLL(None).sleep, 60)
    sys.exit(run(refuse, "refused_stuck_exit"))
