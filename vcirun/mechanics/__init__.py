"""Symbolic mechanical systems: `MechanicalSystem`, safe expression parsing, YAML declarations.
(The built-in scenes' declarations are `vcirun.scenes.registry`, one `vcirun.scenes.scene.Scene` each.)"""
from .expressions import ExpressionError, parse_expression
from .loader import load_system_yaml
from .system import MechanicalSystem

__all__ = ["MechanicalSystem", "load_system_yaml", "ExpressionError", "parse_expression"]
