"""vcirun: event-driven variational collision integrators (Pekarek & Murphey) as an experiment runner.

Python API: `simulate`, `reference`, `l2_error`; command line: `vcirun --help`.
"""
__version__ = "0.1.0"

from .api import simulate  # noqa: E402
from .reference import l2_error, reference  # noqa: E402
from .trajectory import Trajectory  # noqa: E402

__all__ = ["simulate", "reference", "l2_error", "Trajectory", "__version__"]
