"""vcirun: event-driven variational collision integrators (Pekarek & Murphey) as an experiment runner."""
__version__ = "0.1.0"
