"""riskfield wire contract v1: messages, keys and the msgpack codec.

Depends on numpy, pydantic and msgpack only, so an external planner can subscribe to the
ESDF key with nothing else of riskfield installed::

    from riskfield.protocol import EsdfGrid, Keys, decode
    grid = decode(sample.payload.to_bytes(), EsdfGrid)
"""

from . import ade20k
from .codec import DEFAULT_LIMITS, ENCODING, REGISTRY, Limits, decode, encode, to_map
from .errors import DecodeError, EncodeError
from .keys import TOPICS, Keys
from .messages import (
    CERTAIN_CONFIDENCE,
    MESSAGE_TYPES,
    Alignment,
    CommandLock,
    DepthImage,
    DistanceQuery,
    DistanceReply,
    EsdfGrid,
    Header,
    Image,
    LimoDiagnostics,
    Message,
    NavGoal,
    NodeStatus,
    PerceptionFrame,
    RobotState,
    SafetyStatus,
    SimActor,
    SimActors,
    TrackedObject,
    TrackedObjects,
    VelocityCommand,
)
from .risk import RiskConfig, RiskGroup

__all__ = [
    "CERTAIN_CONFIDENCE", "DEFAULT_LIMITS", "ENCODING", "MESSAGE_TYPES", "REGISTRY", "TOPICS", "Alignment",
    "CommandLock",
    "DecodeError", "DepthImage", "DistanceQuery", "DistanceReply", "EncodeError", "EsdfGrid", "Header", "Image",
    "Keys", "Limits", "LimoDiagnostics", "Message", "NavGoal", "NodeStatus", "PerceptionFrame", "RiskConfig",
    "RiskGroup",
    "RobotState", "SafetyStatus", "SimActor", "SimActors", "TrackedObject", "TrackedObjects",
    "VelocityCommand", "ade20k", "decode", "encode", "to_map",
]
