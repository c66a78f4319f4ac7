"""hypothesis strategies producing arbitrary valid messages of the wire contract."""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from riskfield.protocol import (
    DistanceQuery,
    DistanceReply,
    EsdfGrid,
    Header,
    Image,
    NavGoal,
    NodeStatus,
    PerceptionFrame,
    RiskConfig,
    RiskGroup,
    RobotState,
    SafetyStatus,
    VelocityCommand,
)

finite = st.floats(allow_nan=False, allow_infinity=False, min_value=-1e6, max_value=1e6, width=64)
finite32 = st.floats(allow_nan=False, allow_infinity=False, min_value=-1e6, max_value=1e6, width=32)
vec3 = st.tuples(finite, finite, finite)
text = st.text(max_size=20)
headers = st.builds(Header, stamp_ns=st.integers(0, 2**63 - 1), frame_id=text, seq=st.integers(0, 2**63 - 1))


def arrays(dtype: str, shape, elements=None):
    return hnp.arrays(np.dtype(dtype), shape, elements=elements)


@st.composite
def unit_quaternions(draw):
    v = np.array(draw(st.tuples(*[st.floats(-1, 1)] * 4)))
    n = np.linalg.norm(v)
    if n < 1e-3:
        return (0.0, 0.0, 0.0, 1.0)
    return tuple(float(c) for c in v / n)


@st.composite
def images(draw):
    h, w = draw(st.integers(1, 8)), draw(st.integers(1, 8))
    if draw(st.booleans()):
        return Image(header=draw(headers), encoding="rgb8", width=w, height=h, data=draw(arrays("|u1", (h, w, 3))))
    return Image(header=draw(headers), encoding="jpeg", width=w, height=h,
                 data=b"\xff\xd8\xff" + draw(st.binary(min_size=1, max_size=64)))


@st.composite
def perception_frames(draw):
    h, w = draw(st.integers(1, 6)), draw(st.integers(1, 6))
    return PerceptionFrame(
        header=draw(headers),
        T_WC=draw(arrays("<f8", (4, 4), finite)),
        points=draw(arrays("<f4", (h, w, 3), finite32)),
        confidence=draw(arrays("<f4", (h, w), finite32)),
        labels=draw(arrays("<u2", (h, w))),
        keyframe_id=draw(st.integers(-(2**31), 2**31)),
    )


@st.composite
def esdf_grids(draw):
    shape = draw(st.tuples(st.integers(0, 5), st.integers(0, 5), st.integers(0, 4)))
    groups = draw(st.lists(st.text(min_size=1, max_size=5), min_size=0, max_size=4))
    return EsdfGrid(
        header=draw(headers),
        origin=draw(vec3),
        voxel_size=draw(st.floats(1e-3, 10)),
        distance=draw(arrays("<f4", shape, finite32)),
        risk_group=draw(arrays("|u1", shape, st.integers(0, len(groups)))),
        groups=groups,
        max_distance=draw(st.floats(1e-3, 100)),
        unknown_is_occupied=draw(st.booleans()),
    )


@st.composite
def distance_replies(draw):
    n = draw(st.integers(0, 6))
    return DistanceReply(
        header=draw(headers),
        distance=draw(arrays("<f8", (n,), finite)),
        gradient=draw(arrays("<f8", (n, 3), finite)),
        risk_group=draw(arrays("|u1", (n,))),
        in_map=draw(st.none() | arrays("|b1", (n,))),
    )


@st.composite
def risk_configs(draw):
    names = draw(st.lists(st.text(min_size=1, max_size=6), min_size=1, max_size=4, unique=True))
    labels = draw(st.lists(st.integers(0, 65535), unique=True, max_size=12))
    groups = [RiskGroup(name=n, labels=labels[i::len(names)], margin=draw(st.floats(0, 1)),
                        alpha=draw(st.floats(0.01, 10)), alpha1=draw(st.floats(0.01, 10)),
                        alpha2=draw(st.floats(0.01, 10))) for i, n in enumerate(names)]
    free = draw(st.lists(st.integers(0, 65535), max_size=5))
    return RiskConfig(header=draw(headers), groups=groups, free_labels=free,
                      # no labels and no default group names no obstacle: refused (RiskConfig's floor)
                      default_group=draw((st.none() if labels else st.nothing()) | st.sampled_from(names)))


messages = st.one_of(
    images(),
    perception_frames(),
    esdf_grids(),
    st.builds(DistanceQuery, header=headers, points=arrays("<f8", st.tuples(st.integers(0, 6), st.just(3)), finite)),
    distance_replies(),
    st.builds(RobotState, header=headers, position=vec3, orientation=unit_quaternions(), linear_velocity=vec3,
              angular_velocity=vec3),
    st.builds(VelocityCommand, header=headers, linear=vec3, angular=vec3, source=text),
    st.builds(SafetyStatus, header=headers, h=finite, risk_group=st.integers(0, 255), intervening=st.booleans(),
              fallback=st.none() | text, solve_us=st.floats(0, 1e6), esdf_age_ms=finite),
    st.builds(NavGoal, header=headers, waypoints=arrays("<f8", st.tuples(st.integers(1, 5), st.just(3)), finite),
              tolerance=st.floats(1e-3, 10), loop=st.booleans()),
    st.builds(NodeStatus, header=headers, service=text, received=st.dictionaries(text, st.integers(0, 10**9))),
    risk_configs(),
)
