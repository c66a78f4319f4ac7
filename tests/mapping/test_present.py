"""The map shows the present (issue 23), on the pure core: frames at 10 Hz (stamps 0.1 s apart) of
a room seen long enough to saturate its free space, then a person who steps in, stands and leaves,
or walks; furniture and people out of view. Both ways frames arrive: without ``kind`` (the default
perception mode) and under the keyframe protocol (one ``keyframe_new``, then ``tracking`` frames)."""

from __future__ import annotations

import numpy as np
import pytest

from riskfield.protocol import Header, PerceptionFrame, ade20k
from riskfield.services.geometry.camera import PinholeCamera
from riskfield.services.geometry.shapes import Box, Plane, render
from riskfield.services.geometry.transforms import look_at
from riskfield.services.mapping.config import MapperConfig
from riskfield.services.mapping.layers import SemanticLayer, TsdfLayer
from riskfield.services.mapping.mapper import Mapper
from riskfield.services.mapping.objects import ObjectTracker
from riskfield.services.mapping.present import PresentLayer

CAM = PinholeCamera.centred(160, 120, 125.0)
K = (CAM.fx, CAM.fy, CAM.cx, CAM.cy)
PERSON, CHAIR = ade20k.index("person"), ade20k.index("chair")
ROOM = [Plane((1, 0, 0), 2.5, ade20k.index("wall")), Plane((0, 0, 1), 0.0, ade20k.index("floor"))]
STEP = 100_000_000  # 10 Hz
AHEAD = look_at(np.array([0.0, 0.0, 0.3]), np.array([2.0, 0.0, 0.3]))
AWAY = look_at(np.array([0.0, 0.0, 0.3]), np.array([-2.0, 0.0, 0.3]))  # the person is behind the camera


def person(x: float = 1.0, y: float = 0.0) -> Box:
    return Box((x, y - 0.2, 0.0), (x + 0.3, y + 0.2, 1.7), PERSON)


class Feed:
    """A mapper fed 10 Hz frames, ``kind`` None or the keyframe protocol."""

    def __init__(self, protocol: bool, q: float, config: MapperConfig | None = None, track: bool = False):
        self.m = Mapper(config or MapperConfig())
        self.m.set_robot_position(np.zeros(3))
        self.protocol, self.q, self.t = protocol, q, 1
        # as the node does: the tracker after each map update, then the walkers it gives up on
        self.tracker = ObjectTracker.of(self.m.config) if track else None

    def frame(self, scene: list, T: np.ndarray = AHEAD, q: float | None = None, dt_ns: int = STEP) -> None:
        pts, conf, lab = render(scene, T, CAM, confidence=self.q if q is None else q)
        kind = None
        if self.protocol:
            kind = "keyframe_new" if self.t == 1 else "tracking"
        self.m.integrate_frame(PerceptionFrame(header=Header(stamp_ns=self.t), T_WC=T, points=pts, confidence=conf,
                                               labels=lab, keyframe_id=0, kind=kind, intrinsics=K))
        self.t += dt_ns
        update = self.m.update_esdf()
        if self.tracker is not None and update is not None and update.occupancy is not None:
            self.tracker.update_map(self.m.reading(update.occupancy))
            self.m.dynamic.protected = self.tracker.protected()

    def at(self, x: float, y: float = 0.0) -> tuple[float, int]:
        s = self.m.query(np.array([[x, y, 0.3]]))
        return float(s.distance[0]), int(s.risk_group[0])

    def shows_person(self, x: float = 1.0, y: float = 0.0) -> bool:
        d, g = self.at(x - 0.2, y)  # 0.2 m in front of its face: 0.05 m inside the 0.15 m high-risk margin
        return d < 0.1 and g == 1


def frames_until(feed: Feed, scene: list, done, limit: int = 30) -> int:
    for i in range(1, limit + 1):
        feed.frame(scene)
        if done():
            return i
    return limit + 1


@pytest.mark.parametrize("protocol", [False, True])
@pytest.mark.parametrize(("q", "bound"), [(7.0, 2), (4.0, 3), (2.0, 5)])
def test_a_person_in_long_seen_free_space_appears_within_a_few_frames(protocol: bool, q: float, bound: int) -> None:
    """At the ``sim`` backend's confidence of a fresh keyframe (≈ 7) within 2 frames, 0.2 s at
    10 Hz, and within a few at lower confidence: free space is capped at ``max_free_weight`` and a
    surface voxel weighs the pixels it covers, so a surface is not drowned by the free space around it."""
    feed = Feed(protocol, q)
    for _ in range(30):
        feed.frame(ROOM)
    assert not feed.shows_person()
    assert frames_until(feed, [*ROOM, person()], feed.shows_person) <= bound


@pytest.mark.parametrize("protocol", [False, True])
def test_the_space_a_person_left_clears_within_a_second(protocol: bool) -> None:
    """A person who stood 3 s leaves; the robot does not move: the space clears within 7 frames at
    confidence 2 (0.7 s), and no frame later shows the person again."""
    feed = Feed(protocol, 2.0)
    for _ in range(10):
        feed.frame(ROOM)
    for _ in range(30):
        feed.frame([*ROOM, person()])
    assert feed.shows_person()
    assert frames_until(feed, ROOM, lambda: feed.at(0.8)[0] > 0.5) <= 7
    for _ in range(20):
        feed.frame(ROOM)
        assert feed.at(0.8)[0] > 0.5


@pytest.mark.parametrize("protocol", [False, True])
def test_a_walking_person_stays_high_risk_where_they_are_now(protocol: bool) -> None:
    """A person crossing at 1.2 m/s, 1 m ahead: from the third frame on, every map has them (high
    risk) where they are in that frame, and the space they left 0.9 s before is free again (the
    trail behind a walker is 0.2–0.4 m: their interior, seen for 3 frames, takes 3–4 to carve)."""
    feed = Feed(protocol, 7.0)
    for _ in range(20):
        feed.frame(ROOM)
    ys = np.arange(-0.6, 0.65, 0.12)  # in view: the half field of view is 0.64 m wide at 1 m
    for i, y in enumerate(ys):
        feed.frame([*ROOM, person(1.0, y)])
        if i >= 2:
            assert feed.shows_person(1.0, y), (i, y, feed.at(0.8, y))
        if i >= 9:
            assert feed.at(0.8, ys[i - 9])[0] > 0.3


@pytest.mark.parametrize("protocol", [False, True])
def test_people_out_of_view_persist_for_T_then_decay_furniture_stays(protocol: bool) -> None:
    c = MapperConfig()
    T = c.dynamic_persist_s
    feed = Feed(protocol, 7.0)
    chair = Box((1.0, 0.3, 0.0), (1.4, 0.6, 0.5), CHAIR)
    for _ in range(10):
        feed.frame([*ROOM, person(), chair])
    assert feed.shows_person() and feed.at(0.9, 0.45)[0] < 0.1
    n = round(T / 0.1)
    for _ in range(n - 2):  # the camera looks away for just under T
        feed.frame(ROOM, AWAY)
    assert feed.shows_person()
    for _ in range(4):  # and past T (the decay looks every 0.1 s of frame time)
        feed.frame(ROOM, AWAY)
    d, g = feed.at(0.8)
    assert g != 1 and d > 0.25  # the person is gone (the nearest obstacle is the chair, 0.3 m away)
    for _ in range(30):  # 30 s more, a frame a second: the chair stays
        feed.frame(ROOM, AWAY, dt_ns=10 * STEP)
    assert feed.at(0.9, 0.45)[0] < 0.1 and feed.at(0.9, 0.45)[1] != 1


@pytest.mark.parametrize("protocol", [False, True])
def test_a_walker_out_of_view_is_forgotten_after_T_w(protocol: bool) -> None:
    """A person crossing 1 m ahead at 1.2 m/s, then the camera looks away: where they were last seen
    is free by T_w + 0.3 s with the tracker (``dynamic_moving_persist_s``), where the fixed decay of
    people (T = 3 s) alone still shows them."""
    c = MapperConfig()
    frames = round((c.dynamic_moving_persist_s + 0.3) / 0.1)
    held = {}
    for track in (True, False):
        feed = Feed(protocol, 7.0, track=track)
        for _ in range(20):
            feed.frame(ROOM)
        ys = np.arange(-0.5, 0.3, 0.12)
        for y in ys:
            feed.frame([*ROOM, person(1.0, y)])
        assert feed.shows_person(1.0, ys[-1])
        for _ in range(frames):
            feed.frame(ROOM, AWAY)
        held[track] = feed.shows_person(1.0, ys[-1])
    assert held == {True: False, False: True}


@pytest.mark.parametrize("protocol", [False, True])
def test_the_space_a_person_left_clears_fast_through_low_confidence_rays(protocol: bool) -> None:
    """As the ``sim`` backend weighs them: a person at 1 m at confidence 7, the wall 8.9 m behind at
    1.8 (beyond ``max_depth``: it only carves). The space they left clears within 4 frames; with a
    person's voxels weighted like the rest (``dynamic_max_weight`` = ``max_weight``), not within 7."""
    far = [Plane((1, 0, 0), 8.9, ade20k.index("wall")), Plane((0, 0, 1), 0.0, ade20k.index("floor"))]

    def cleared_after(config: MapperConfig) -> int:
        feed = Feed(protocol, 1.8, config)
        for _ in range(10):
            feed.frame(far)
        for _ in range(30):
            feed.frame([*far, person()], q=7.0)
        assert feed.shows_person()
        return frames_until(feed, far, lambda: feed.at(0.8)[0] > 0.5, limit=10)

    assert cleared_after(MapperConfig()) <= 4
    assert cleared_after(MapperConfig(dynamic_max_weight=MapperConfig().max_weight)) > 7


def test_a_standing_person_out_of_view_is_not_forgotten_early() -> None:
    """A person who stood still when last seen stays T = ``dynamic_persist_s``, tracker or not."""
    feed = Feed(False, 7.0, track=True)
    for _ in range(10):
        feed.frame([*ROOM, person()])
    for _ in range(round(feed.m.config.dynamic_persist_s / 0.1) - 2):
        feed.frame(ROOM, AWAY)
    assert feed.shows_person() and feed.m.dynamic.forgotten_voxels == 0


def overlay_mask(present: PresentLayer, tsdf: TsdfLayer) -> np.ndarray:
    """``PresentLayer.over``'s rule by array operations: where the present layer has observed a voxel
    and the keyframes have not, or they disagree on whether it is an obstacle."""
    p, mw, band = present.tsdf, present.min_weight, present.surface_band
    assert p is not None
    seen_p, seen_t = p.weight >= mw, tsdf.weight >= mw
    return seen_p & (~seen_t | ((seen_p & (p.tsdf <= band)) != (seen_t & (tsdf.tsdf <= band))))


def test_the_compiled_overlay_equals_its_array_definition() -> None:
    """``PresentLayer.over`` (one compiled pass) against its rule by array operations."""
    rng = np.random.default_rng(3)
    shape = (10, 10, 10)
    base, base_sem = TsdfLayer(shape, 0.15), SemanticLayer(shape)
    present = PresentLayer(shape, 0.15, min_weight=0.5, surface_band=0.0375)
    top, top_sem = present.layers()
    for t, s in ((base, base_sem), (top, top_sem)):
        t.tsdf[...] = rng.uniform(-0.15, 0.15, shape)
        t.weight[...] = rng.choice([0.0, 0.3, 1.0, 20.0], shape)
        t.view[...] = rng.integers(-127, 128, (*shape, 3))
        s.label[...] = rng.integers(0, 150, shape)
        s.vote[...] = rng.uniform(0, 5, shape)
    use = overlay_mask(present, base)
    ct, cs = present.over(base, base_sem)
    assert 0 < present.overlaid == use.sum() < use.size
    for out, b, t in ((ct.tsdf, base.tsdf, top.tsdf), (ct.weight, base.weight, top.weight),
                      (cs.label, base_sem.label, top_sem.label), (cs.vote, base_sem.vote, top_sem.vote)):
        np.testing.assert_array_equal(out, np.where(use, t, b))
    np.testing.assert_array_equal(ct.view, np.where(use[..., None], top.view, base.view))


def test_without_a_present_layer_the_keyframes_are_read_and_a_clear_is_nothing() -> None:
    shape = (4, 4, 4)
    base, base_sem = TsdfLayer(shape, 0.15), SemanticLayer(shape)
    present = PresentLayer(shape, 0.15, min_weight=0.5, surface_band=0.0375)
    assert present.over(base, base_sem) == (base, base_sem)
    assert not present.clear() and present.clears == 0
    top, _ = present.layers()
    top.weight[...] = 1.0
    assert present.clear() and present.clears == 1 and not top.weight.any()


@pytest.mark.parametrize(("width", "ahead"), [(512, 2.0), (256, 3.0)])
@pytest.mark.parametrize("integration", ["projective", "merged"])
def test_a_person_crossing_in_simulator_truth_frames_stays_in_the_map(integration: str, width: int,
                                                                      ahead: float) -> None:
    """The simulator's ``sim/truth`` (depth + intrinsics at ``truth_stride``, ``CERTAIN_CONFIDENCE``,
    no ``kind``: what a depth camera sends too) of a person cylinder crossing ahead at 1.5 m/s
    through free space seen for 2 s: from the third frame on, every map has them where they are.
    Weighting a voxel's surface observation by one pixel's confidence (not by the pixels it covers,
    as the ray integrators' rays do) showed them in ~15 % of the maps projectively. With the crowd
    bench's 256-pixel camera at 3 m a voxel holds about one strided pixel: with the truth at
    confidence 1 (MASt3R's least certain pixel) the person was missing from the third frame's map."""
    pytest.importorskip("open3d")
    from riskfield.protocol.platforms import LIMO
    from riskfield.services.geometry.camera import T_base_camera
    from riskfield.services.geometry.transforms import pose_matrix
    from riskfield.services.simulator import procedural, shapes
    from riskfield.services.simulator.camera import Renderer
    from riskfield.services.simulator.node import SimulatorSettings, truth_frame
    from riskfield.services.simulator.scene import Scene, SceneObject

    cam = PinholeCamera.from_fov(width, width * 3 // 4, 90.0)
    renderer, stride = Renderer(cam), int(SimulatorSettings.model_fields["truth_stride"].default)
    T_WC = T_base_camera(LIMO.camera)
    room, body = procedural.room(8, 8), shapes.cylinder(0.25, 1.7)
    m = Mapper(MapperConfig(integration=integration, centre_offset=(1.0, 0.0, 0.0)))  # the map reaches 3.5 m ahead
    m.set_robot_position(np.zeros(3))

    def frame(i: int, walker: list) -> None:
        f = renderer.render(Scene([*room, *walker]).at(0.0), T_WC)
        m.integrate_frame(truth_frame(f, cam, stride, Header(stamp_ns=1 + i * STEP), i))
        m.update_esdf()

    for i in range(20):
        frame(i, [])
    ys = np.arange(-1.2, 1.25, 0.15)  # 1.5 m/s at 10 Hz, in view (the half field of view is ≥ 2 m wide)
    for i, y in enumerate(ys):
        frame(20 + i, [SceneObject("walker", PERSON, body, pose_matrix(ahead, y))])
        if i >= 2:
            s = m.query(np.array([[ahead - 0.35, y, 0.3]]))  # 0.1 m in front of their face
            assert s.distance[0] < 0.1 and s.risk_group[0] == 1, (i, y, float(s.distance[0]))
