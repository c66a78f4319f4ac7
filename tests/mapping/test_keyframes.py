"""The keyframe map-update protocol: new keyframes integrate once, updates replace their previous
contribution (de-integration), tracking frames reach the present layer, memory stays bounded."""

from __future__ import annotations

import numpy as np

from riskfield.protocol import Header, PerceptionFrame
from riskfield.services.geometry.camera import PinholeCamera as Camera
from riskfield.services.geometry.shapes import render
from riskfield.services.geometry.transforms import look_at
from riskfield.services.mapping.config import MapperConfig
from riskfield.services.mapping.keyframes import ContributionIntegrator, KeyframeMap
from riskfield.services.mapping.layers import TsdfLayer
from riskfield.services.mapping.mapper import Mapper
from riskfield.services.mapping.volume import Volume

V = 0.05


def frame(scene: list, camera: Camera, T_true: np.ndarray, T_pub: np.ndarray, kid: int, kind: str | None,
          stamp: int = 1) -> PerceptionFrame:
    points, conf, labels = render(scene, T_true, camera, confidence=2.0)
    return PerceptionFrame(header=Header(stamp_ns=stamp), T_WC=T_pub, points=points, confidence=conf,
                           labels=labels, keyframe_id=kid, kind=kind)


def poses() -> list[np.ndarray]:
    eyes = [(0.0, -0.3, 0.4), (0.0, 0.0, 0.4), (0.1, 0.3, 0.4)]
    return [look_at(np.array(e), np.array([1.2, 0.0, 0.3])) for e in eyes]


def drift(T: np.ndarray, dx: float = 0.25, yaw: float = 0.12) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    D = np.eye(4)
    D[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    D[:3, 3] = (dx, -0.5 * dx, 0.0)
    return D @ T


def mapper() -> Mapper:
    m = Mapper(MapperConfig(output="3d", pixel_stride=1, max_distance=1.5))
    m.set_robot_position(np.zeros(3))
    return m


def test_a_correction_reaches_the_esdf_within_one_voxel(room: list, small_camera: Camera) -> None:
    Ts = poses()
    # Reference: every keyframe integrated once at its corrected (true) pose.
    ref = mapper()
    for i, T in enumerate(Ts):
        ref.integrate_frame(frame(room, small_camera, T, T, i, "keyframe_new"))
    # Drifted: keyframe 2 first arrives with a drifted pose, then the loop closure re-poses it.
    m = mapper()
    for i, T in enumerate(Ts):
        m.integrate_frame(frame(room, small_camera, T, drift(T) if i == 2 else T, i, "keyframe_new"))
    observed = ref.tsdf.weight > 0
    d_ref = ref.update_esdf().grid3d.distance  # type: ignore[union-attr]
    d_drift = m.update_esdf().grid3d.distance  # type: ignore[union-attr]
    assert np.abs(d_drift - d_ref)[observed].max() > 2 * V  # the drift is visible in the map
    m.integrate_frame(frame(room, small_camera, Ts[2], Ts[2], 2, "keyframe_update"))
    # The re-pose cleared the present layer (built in the drifted frame of reference): the map is
    # the keyframes' until the next frames, so the reference is too.
    assert m.present.clears == 1
    ref.clear_present()
    d_ref = ref.update_esdf().grid3d.distance  # type: ignore[union-attr]
    d_fixed = m.update_esdf().grid3d.distance  # type: ignore[union-attr]
    assert np.abs(d_fixed - d_ref)[observed].max() <= V
    assert m.keyframes.counts["keyframe_update"] == 1 and len(m.keyframes) == 3
    # Without de-integration (the same update as an independent observation) the ghost stays.
    smear = mapper()
    for i, T in enumerate(Ts):
        smear.integrate_frame(frame(room, small_camera, T, drift(T) if i == 2 else T, i, "keyframe_new"))
    smear.integrate_frame(frame(room, small_camera, Ts[2], Ts[2], 2, None))
    d_smear = smear.update_esdf().grid3d.distance  # type: ignore[union-attr]
    assert np.abs(d_smear - d_ref)[observed].max() > 2 * V


def test_de_integration_is_the_exact_inverse(room: list, small_camera: Camera) -> None:
    cfg = MapperConfig(pixel_stride=1)
    vol = Volume.centred(V, cfg.shape, np.zeros(3))
    layer = TsdfLayer(cfg.shape, cfg.truncation)
    ci = ContributionIntegrator(cfg.tsdf, cfg.surface_band)
    a, b = poses()[0], poses()[1]
    ca, _, _ = ci.contribution(vol, *render(room, a, small_camera), a)
    cb, _, _ = ci.contribution(vol, *render(room, b, small_camera), b)
    ci.apply(vol, layer, ca, +1)
    before = layer.tsdf.copy(), layer.weight.copy()
    ci.apply(vol, layer, cb, +1)
    assert not np.allclose(layer.weight, before[1])
    ci.apply(vol, layer, cb, -1)
    np.testing.assert_allclose(layer.weight, before[1], atol=1e-4)
    np.testing.assert_allclose(layer.tsdf[before[1] > 0], before[0][before[1] > 0], atol=1e-4)
    ci.apply(vol, layer, ca, -1)
    assert not layer.observed.any()


def test_contribution_equals_the_mappers_own_integration(room: list, small_camera: Camera) -> None:
    """Merging (d_k, w_k) gives what the integrator's ray-by-ray updates give (below the cap)."""
    T = poses()[1]
    direct = mapper()
    # The same confidence as ``frame``: with free space's own weight cap the mean is no longer
    # invariant to scaling every confidence.
    direct.integrate(*render(room, T, small_camera, confidence=2.0), T)
    via = mapper()
    via.integrate_frame(frame(room, small_camera, T, T, 0, "keyframe_new"))
    w_direct, w_via = direct.tsdf.weight, via.tsdf.weight
    np.testing.assert_array_equal(w_direct > 0, w_via > 0)
    below = (w_direct > 0) & (w_direct < direct.config.max_weight)
    np.testing.assert_allclose(via.tsdf.tsdf[below], direct.tsdf.tsdf[below], atol=1e-4)
    # one keyframe alone: the viewing directions behind surfaces are its own rays' (±1 of 127: renormalised)
    np.testing.assert_array_equal(via.tsdf.view.any(axis=-1), direct.tsdf.view.any(axis=-1))
    assert np.abs(via.tsdf.view.astype(int) - direct.tsdf.view.astype(int)).max() <= 1


def test_tracked_frames_reach_the_present_layer_and_only_new_data_stamps(room: list, small_camera: Camera) -> None:
    """A tracked frame's geometry goes to the present layer (not to any keyframe's contribution)
    and stamps the map; a re-sent keyframe and a frame with no usable pixel change no stamp."""
    m = mapper()
    T = poses()[0]
    m.integrate_frame(frame(room, small_camera, T, T, 0, "keyframe_new", stamp=10))
    w = m.tsdf.weight.copy()
    m.update_esdf()
    assert not m.dirty and m.stamp_ns == 10
    assert m.present.tsdf is not None
    p = m.present.tsdf.weight.copy()
    m.integrate_frame(frame(room, small_camera, poses()[1], poses()[1], 0, "tracking", stamp=20))
    np.testing.assert_array_equal(m.tsdf.weight, w)  # no keyframe's contribution changed
    assert (m.present.tsdf.weight != p).any()
    assert m.dirty and m.stamp_ns == 20 and m.keyframes.counts["tracking"] == 1
    m.update_esdf()
    m.integrate_frame(frame(room, small_camera, T, T, 0, "keyframe_update", stamp=30))  # re-sent: no new data
    assert m.stamp_ns == 20 and m.present.clears == 0
    blind = frame(room, small_camera, T, T, 0, "tracking", stamp=40)
    blind = blind.model_copy(update={"confidence": np.zeros_like(blind.confidence)})
    m.update_esdf()
    m.integrate_frame(blind)
    assert m.stamp_ns == 20 and not m.dirty


def test_memory_is_bounded_and_frozen_keyframes_ignore_updates(room: list, small_camera: Camera) -> None:
    m = mapper()
    m.keyframes = KeyframeMap.of(m.config, max_keyframes=2)
    Ts = poses()
    for i, T in enumerate(Ts):
        m.integrate_frame(frame(room, small_camera, T, T, i, "keyframe_new"))
    assert len(m.keyframes) == 2 and m.keyframes.frozen == {0}
    assert m.keyframes.nbytes == sum(c.nbytes for c in m.keyframes.records.values())
    w = m.tsdf.weight.copy()
    m.integrate_frame(frame(room, small_camera, Ts[0], drift(Ts[0]), 0, "keyframe_update"))
    np.testing.assert_array_equal(m.tsdf.weight, w)  # cannot be subtracted any more: ignored
    assert m.keyframes.counts["frozen_updates"] == 1
    # an update of a keyframe the mapper never saw (it started late) is integrated as new
    m.integrate_frame(frame(room, small_camera, Ts[0], Ts[0], 7, "keyframe_update"))
    assert 7 in m.keyframes.records


def test_contributions_survive_recentring(room: list, small_camera: Camera) -> None:
    m = mapper()
    T = poses()[1]
    m.integrate_frame(frame(room, small_camera, T, T, 0, "keyframe_new"))
    assert m.set_robot_position(np.array([0.4, 0.0, 0.0]))  # the volume shifts
    m.integrate_frame(frame(room, small_camera, T, T, 0, "keyframe_update"))
    m.integrate_frame(frame(room, small_camera, T, T, 0, "keyframe_update"))
    ref = mapper()
    ref.set_robot_position(np.array([0.4, 0.0, 0.0]))
    ref.integrate_frame(frame(room, small_camera, T, T, 0, "keyframe_new"))
    np.testing.assert_allclose(m.tsdf.weight, ref.tsdf.weight, atol=1e-3)
