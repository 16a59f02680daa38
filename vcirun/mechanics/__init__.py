"""Symbolic mechanical systems, built-in scenes and user-declared systems."""
from .expressions import ExpressionError, parse_expression
from .loader import load_system_yaml
from .scenes import BUILTIN_SCENES, get_scene
from .system import MechanicalSystem

__all__ = ["MechanicalSystem", "BUILTIN_SCENES", "get_scene", "load_system_yaml", "ExpressionError", "parse_expression"]
