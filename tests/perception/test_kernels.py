"""The sim backend's compiled kernels (``perception.kernels``) against their numpy renderings
(``oracles.sim_perception``): the published frames are byte-identical, in every publish mode, with
noise, label errors and drift."""

from __future__ import annotations

import numpy as np
import pytest

from oracles.sim_perception import NumpyDegrader, NumpySimBackend
from riskfield.protocol import PerceptionFrame, encode
from riskfield.services.perception.degrade import DegradationConfig, Degrader
from riskfield.services.perception.sim_backend import SimBackend, SimBackendConfig
from riskfield.services.runtime import jit
from riskfield.services.simulator.scenario import load_scenario
from riskfield.services.simulator.world import World

SCENE = {"room": {"size": [6.0, 5.0]}, "camera": {"width": 160, "height": 120},
         "robot": {"type": "limo", "start": [-1.5, 0.0, 0.0]},
         "objects": [{"class": "animal", "position": [0.5, 0.3]}, {"class": "box", "position": [1.0, -0.8]},
                     {"class": "chair", "position": [2.0, 1.2]}, {"class": "ball", "position": [0.0, -0.5]}]}


def truths(n: int) -> list[PerceptionFrame]:
    world = World(load_scenario(SCENE))
    out = []
    for i in range(n):
        # turning fast enough that keyframes change, slowly enough that most frames fuse
        world.command(np.array([0.3, 0.0, 0.0]), np.array([0.0, 0.0, 0.6 if i < n // 2 else -0.8]))
        world.advance(0.1)
        r = world.render()
        out.append(PerceptionFrame(T_WC=r.T_WC, points=r.points, confidence=r.valid.astype(np.float32),
                                   labels=r.labels, keyframe_id=i))
    return out


@pytest.mark.parametrize("publish", ["keyframe", "frame", "updates"])
def test_compiled_backend_publishes_the_same_bytes_as_numpy(publish: str) -> None:
    deg = DegradationConfig(p_confuse=0.5, p_salt=0.01, drift_t=0.01, drift_yaw=0.01)
    cfg = SimBackendConfig(degradation=deg, publish=publish, kf_min_overlap=0.8, correct_every=2, seed=3)
    frames = truths(14)
    ref, fast = NumpySimBackend(cfg), SimBackend(cfg)
    for i, truth in enumerate(frames):
        a = [encode(f) for f in ref.process(None, truth, i + 1)]
        b = [encode(f) for f in fast.process(None, truth, i + 1)]
        assert a == b, f"frame {i} differs"
    assert ref.n_keyframes == fast.n_keyframes >= 2  # new keyframes and fused frames both ran
    assert fast.frames - fast.n_keyframes >= 3


def test_compiled_degradation_matches_numpy_on_random_pointmaps() -> None:
    rng = np.random.default_rng(7)
    for _ in range(5):
        h, w = rng.integers(1, 40, 2)
        points = rng.normal(0.0, 1.0, (h, w, 3)).astype(np.float32)
        points[..., 2] = np.abs(points[..., 2]) * 3  # some at z = 0 after rounding, most in front
        points[rng.random((h, w)) < 0.1] = 0.0
        valid = (rng.random((h, w)) < 0.9) & (points[..., 2] > 0)
        labels = rng.integers(0, 150, (h, w)).astype(np.uint16)
        a = NumpyDegrader(seed=1).observe(points, labels, np.eye(4), valid)
        b = Degrader(seed=1).observe(points, labels, np.eye(4), valid)
        for name in ("points", "confidence", "labels", "T_WC", "valid"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_without_numba_the_backend_names_what_to_install(monkeypatch):
    monkeypatch.setattr(jit, "HAVE_NUMBA", False)  # an install without numba
    for build in (SimBackend, Degrader):
        with pytest.raises(ModuleNotFoundError) as info:
            build()
        assert info.value.name == "numba"
