"""Pure parts of the GPU adapters: MASt3R-SLAM geometry conventions, label transfer through
idx_f2k, Sim(3) → rigid pose + scaled points, the match recorder; EfficientViT pre- and
post-processing, and (where torch is installed) a tiny randomly initialised network through the
real labeller code path. MASt3R-SLAM and EfficientViT themselves cannot run here."""

from __future__ import annotations

import math
import sys
import types

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from riskfield.services.perception.backend import MissingBackend
from riskfield.services.perception.efficientvit_backend import (
    EfficientVitLabeller,
    input_size,
    labels_from_logits,
    normalize,
    resize_bilinear,
    resize_cubic,
)
from riskfield.services.perception.mast3r_backend import (
    KeyframeLabels,
    Mast3rBackend,
    MatchRecorder,
    SlamFrame,
    keyframe_message,
    labels_to_grid,
    mast3r_crop,
    require_mast3r,
    sim3_pose,
)

# -- MASt3R-SLAM ----------------------------------------------------------------------------------


def test_mast3r_crop_of_common_sizes():
    c = mast3r_crop(480, 640)
    assert (c.rh, c.rw) == (384, 512) and c.shape == (384, 512)
    assert mast3r_crop(384, 512).shape == (384, 512)
    assert mast3r_crop(720, 1280).shape == (288, 512)  # 512x288: already multiples of 16
    sq = mast3r_crop(500, 500)
    assert sq.shape == (384, 512)  # a square image is cropped to 4:3
    assert mast3r_crop(500, 500, square_ok=True).shape == (512, 512)


@settings(max_examples=60, deadline=None)
@given(st.integers(64, 2000), st.integers(64, 2000))
def test_mast3r_crop_is_centred_multiple_of_16_inside_the_resized_image(h, w):
    c = mast3r_crop(h, w)
    ch, cw = c.shape
    assert ch % 16 == 0 and cw % 16 == 0 and max(c.rh, c.rw) == 512
    assert 0 <= c.y0 and c.y1 <= c.rh and 0 <= c.x0 and c.x1 <= c.rw
    assert abs((c.y0 + c.y1) / 2 - c.rh // 2) <= 0.5 and abs((c.x0 + c.x1) / 2 - c.rw // 2) <= 0.5


def test_labels_to_grid_nearest_and_cropped():
    labels = np.zeros((480, 640), np.uint16)
    labels[:, 320:] = 12
    labels[:240] += 100
    g = labels_to_grid(labels, mast3r_crop(480, 640))
    assert g.shape == (384, 512) and set(np.unique(g)) == {0, 12, 100, 112}  # never interpolated
    assert g[0, 0] == 100 and g[-1, -1] == 12 and g[0, 255] == 100 and g[0, 256] == 112


def test_sim3_pose_rotation_and_scale():
    a = math.pi / 3
    data = [1.0, 2.0, 3.0, 0.0, 0.0, math.sin(a / 2), math.cos(a / 2), 2.5]
    T, s = sim3_pose(np.array(data))
    np.testing.assert_allclose(T[:3, :3], [[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]],
                               atol=1e-12)
    np.testing.assert_allclose(T[:3, 3], [1, 2, 3])
    assert s == 2.5
    for bad in ([0] * 7, [0, 0, 0, 0, 0, 0, 1, -1.0], [0, 0, 0, 0, 0, 0, 1, float("nan")]):
        with pytest.raises(ValueError):
            sim3_pose(np.array(bad))


def test_keyframe_message_folds_the_scale_into_the_points():
    h, w = 4, 5
    rng = np.random.default_rng(0)
    X = rng.uniform(0.5, 2, (h * w, 3))
    X[3] = np.nan  # a network failure
    C = rng.uniform(1, 5, (h * w, 1))
    data = np.array([0.5, 0, 0, 0, 0, 0, 1, 2.0])
    msg = keyframe_message(SlamFrame(X, C, data, np.full(h * w, 7), (h, w), keyframe_id=4), stamp_ns=99)
    T, s = sim3_pose(data)
    world_sim3 = s * X[5] + data[:3]  # lietorch: p_W = s·R·X + t (R = I here)
    world_msg = T[:3, :3] @ msg.points.reshape(-1, 3)[5] + T[:3, 3]
    np.testing.assert_allclose(world_msg, world_sim3, rtol=1e-6)
    assert msg.confidence.reshape(-1)[3] == 0 and np.all(msg.points.reshape(-1, 3)[3] == 0)
    assert msg.keyframe_id == 4 and msg.header.stamp_ns == 99 and msg.labels.dtype == np.uint16


def test_match_recorder_and_label_fusion_through_idx_f2k():
    h, w = 3, 4
    n = h * w
    idx_f2k = np.roll(np.arange(n), 1)[None]  # keyframe pixel ξ matches frame pixel ξ − 1
    valid = np.ones((1, n), bool)
    valid[0, 0] = False
    Qff = np.full((1, n, 1), 4.0)
    Qkf = np.full((1, n, 1), 1.0)
    Qkf[0, 1] = 0.25  # Qk = sqrt(4 · 0.25) = 1 < 1.5: untrusted
    calls = []

    def fake_match(model, frame, keyframe, idx_i2j_init=None):
        calls.append((frame, keyframe))
        return idx_f2k, valid, None, None, Qff, None, None, Qkf

    rec = MatchRecorder(fake_match)
    assert rec("model", "frame", "kf")[0] is idx_f2k and calls == [("frame", "kf")]
    idx, v, Qk = rec.matches()
    assert Qk[1] == pytest.approx(1.0) and Qk[2] == pytest.approx(2.0)
    kl = KeyframeLabels()
    kl.start(0, np.zeros(n), weight=0.5)
    frame_labels = np.arange(n).reshape(h, w).astype(np.uint16) + 10
    trusted = kl.fuse(0, frame_labels, idx, v, Qk)
    assert trusted.tolist() == [False, False] + [True] * (n - 2)
    # Trusted keyframe pixels ξ ≥ 2 took the frame label at ξ − 1 (one vote of 2 beats weight 0.5).
    assert kl.labels[0].tolist() == [0, 0] + [10 + k - 1 for k in range(2, n)]
    with pytest.raises(RuntimeError):
        MatchRecorder(fake_match).matches()


def test_missing_mast3r_names_what_is_missing_and_how_to_install(monkeypatch: pytest.MonkeyPatch):
    # lietorch importable (a stand-in module), the rest absent here: the message names exactly
    # the modules that failed to import, then how to install them.
    monkeypatch.setitem(sys.modules, "lietorch", types.ModuleType("lietorch"))
    monkeypatch.setitem(sys.modules, "torch", None)  # absent, even where the CPU wheel is installed
    with pytest.raises(MissingBackend) as err:
        require_mast3r()
    text = str(err.value)
    named = [entry.split(" (")[0] for entry in text.split("cannot import ", 1)[1].split(". ", 1)[0].split(", ")]
    assert {"torch", "mast3r_slam", "mast3r_slam.tracker"} <= set(named) and "lietorch" not in named
    assert "CUDA" in text and "princeton-vl/lietorch" in text
    with pytest.raises(MissingBackend):
        Mast3rBackend(labeller=lambda rgb: rgb[..., 0])


# -- EfficientViT -----------------------------------------------------------------------------------


def test_input_size_short_side_512_long_side_multiple_of_32():
    assert input_size(384, 512) == (512, 704)  # 682.7 rounded up to a multiple of 32
    assert input_size(480, 640) == (512, 704)
    assert input_size(512, 512) == (512, 512)
    assert input_size(1280, 720) == (928, 512)
    with pytest.raises(ValueError):
        input_size(0, 10)


def test_resize_bilinear_identities():
    img = np.random.default_rng(0).uniform(0, 1, (7, 9, 3)).astype(np.float32)
    np.testing.assert_allclose(resize_bilinear(img, (7, 9)), img, atol=1e-6)
    flat = np.full((5, 6), 3.0, np.float32)
    np.testing.assert_allclose(resize_bilinear(flat, (17, 11)), 3.0)
    ramp = np.tile(np.arange(4, dtype=np.float32), (2, 1))
    up = resize_bilinear(ramp, (2, 8))  # half-pixel centres: x_in = (x + 0.5)/2 − 0.5
    np.testing.assert_allclose(up[0], [0, 0.25, 0.75, 1.25, 1.75, 2.25, 2.75, 3.0], atol=1e-6)


def test_resize_cubic_identities_and_saturation():
    """Keys' kernel (a = −0.75): same size is the identity, constants are
    kept, a uint8 image overshoots at a step edge and is saturated like cv2.INTER_CUBIC."""
    img = np.random.default_rng(0).uniform(0, 1, (7, 9, 3)).astype(np.float32)
    np.testing.assert_allclose(resize_cubic(img, (7, 9)), img, atol=1e-6)
    np.testing.assert_allclose(resize_cubic(np.full((5, 6), 3.0, np.float32), (17, 11)), 3.0, atol=1e-5)
    # halving a [0, 0, 1, 1] row: the output sample sits half-way, weights W(1.5), W(0.5), W(0.5), W(1.5)
    # = −0.09375, 0.59375, 0.59375, −0.09375 (a = −0.75, not the linear-exact −0.5)
    row = np.array([[0, 0, 0, 1, 1, 1]], np.float32)
    np.testing.assert_allclose(resize_cubic(row, (1, 3))[0, 1], 0.5, atol=1e-6)
    np.testing.assert_allclose(resize_cubic(np.array([[0, 0, 1, 1]], np.float32), (1, 2))[0],
                               [-0.09375, 1.09375], atol=1e-6)
    step = np.zeros((4, 8), np.uint8)
    step[:, 4:] = 255
    out = resize_cubic(step, (4, 32))
    assert out.dtype == np.uint8 and out.max() == 255 and out.min() == 0
    assert resize_cubic(step.astype(np.float32), (4, 32)).max() > 255  # the float result overshoots


def test_resize_cubic_matches_torch_bicubic():
    torch = pytest.importorskip("torch")
    img = np.random.default_rng(2).uniform(-3, 3, (13, 17, 4)).astype(np.float32)
    for size in ((40, 23), (5, 9), (13, 51)):
        ref = torch.nn.functional.interpolate(torch.from_numpy(img.transpose(2, 0, 1))[None], size=size,
                                              mode="bicubic", align_corners=False)[0].numpy().transpose(1, 2, 0)
        np.testing.assert_allclose(resize_cubic(img, size), ref, atol=1e-4)


def test_normalize_layout_and_statistics():
    rgb = np.zeros((384, 512, 3), np.uint8)
    rgb[..., 0] = 255
    x = normalize(rgb)
    assert x.shape == (1, 3, 512, 704) and x.dtype == np.float32
    np.testing.assert_allclose(x[0, 0].mean(), (1 - 0.485) / 0.229, rtol=1e-5)
    np.testing.assert_allclose(x[0, 1].mean(), (0 - 0.456) / 0.224, rtol=1e-5)
    with pytest.raises(ValueError):
        normalize(rgb.astype(np.float32))


def test_labels_from_logits_upsamples_then_argmax():
    logits = np.zeros((150, 4, 4), np.float32)
    logits[12, :, :2] = 5.0  # person on the left half
    logits[126, :, 2:] = 5.0  # animal on the right half
    lab = labels_from_logits(logits[None], 32, 32)
    assert lab.shape == (32, 32) and lab.dtype == np.uint16
    assert np.all(lab[:, :14] == 12) and np.all(lab[:, 18:] == 126)


def test_labeller_needs_a_local_checkpoint(tmp_path):
    pytest.importorskip("torch")
    with pytest.raises(MissingBackend):
        EfficientVitLabeller(checkpoint=None)
    with pytest.raises(MissingBackend, match="does not exist"):
        EfficientVitLabeller(checkpoint=tmp_path / "none.pt")
    ckpt = tmp_path / "model.pt"
    ckpt.write_bytes(b"x")
    with pytest.raises(MissingBackend, match="efficientvit"):  # the model zoo is not installed here
        EfficientVitLabeller(checkpoint=ckpt)


def test_tiny_random_network_through_the_labeller():
    torch = pytest.importorskip("torch")
    torch.manual_seed(0)
    # Same interface as EfficientViT-Seg: (1, 3, H', W') → (1, 150, H'/8, W'/8) logits.
    net = torch.nn.Sequential(torch.nn.Conv2d(3, 8, 3, stride=2, padding=1), torch.nn.ReLU(),
                              torch.nn.Conv2d(8, 16, 3, stride=2, padding=1), torch.nn.ReLU(),
                              torch.nn.Conv2d(16, 150, 3, stride=2, padding=1))
    lab = EfficientVitLabeller(model=net)
    rgb = np.random.default_rng(1).integers(0, 256, (96, 128, 3), dtype=np.uint8)
    out = lab(rgb)
    assert out.shape == (96, 128) and out.dtype == np.uint16 and out.max() < 150
    logits = lab.logits(rgb).numpy()
    assert logits.shape == (1, 150, 64, 88)  # 512 × 683 → 512 × 704, /8
    ref = labels_from_logits(logits, 96, 128)  # the numpy post-processing (bicubic) agrees with torch's
    assert (ref == out).mean() > 0.99
    # The numpy pre-processing agrees with torch's bicubic resize of the uint8 image, rounded and
    # saturated back to uint8 (cv2.INTER_CUBIC on a uint8 image), then /255 and normalised.
    t = torch.from_numpy(rgb.astype(np.float32)).permute(2, 0, 1)[None]
    tr = torch.nn.functional.interpolate(t, size=(512, 704), mode="bicubic", align_corners=False)[0]
    tr = tr.round().clamp(0, 255) / 255
    mean, std = torch.tensor([0.485, 0.456, 0.406])[:, None, None], torch.tensor([0.229, 0.224, 0.225])[:, None, None]
    diff = np.abs(normalize(rgb)[0] - ((tr - mean) / std).numpy())
    assert diff.max() <= 1 / 255 / 0.224 + 1e-4 and (diff < 1e-4).mean() > 0.999  # off by a rounding tie at most
    bad = torch.nn.Conv2d(3, 10, 8, stride=8)
    with pytest.raises(ValueError, match="150"):
        EfficientVitLabeller(model=bad)(rgb)
