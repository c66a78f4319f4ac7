"""A scripted teleoperator: drives towards targets the way a person with a joystick does."""

from .operator import OperatorConfig, ScriptedOperator, Target

__all__ = ["OperatorConfig", "ScriptedOperator", "Target"]
