"""The MASt3R-SLAM adapter's loop against small fakes of upstream (rmurai0610/MASt3R-SLAM at
b0ae540). Each fake reproduces the behaviour of the upstream file and function it names, no more;
none of upstream's code is copied. What they pin down: the config is always loaded (keys,
inheritance, in-place merge), the Sim(3) field order, the average confidence and its threshold,
dirty keyframes versus re-posed ones, relocalisation, the initial pose guess and subsampling."""

from __future__ import annotations

import contextlib
import os
import types
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from riskfield.protocol import Image
from riskfield.services.perception.backend import MissingBackend
from riskfield.services.perception.mast3r_backend import (
    AUTHORS_OVERRIDES,
    C_CONF,
    CHECKPOINT,
    CODEBOOK,
    REQUIRED,
    RETRIEVER,
    Mast3rSlam,
    SlamFrame,
    SlamParams,
    checkout_config,
    keyframe_message,
    load_config,
    sim3_pose,
    startup_check,
)

# -- fakes ------------------------------------------------------------------------------------------


def fake_config_module() -> types.ModuleType:
    """mast3r_slam/config.py: a module-level ``config`` dict; ``load_config(path)`` reads YAML,
    loads an ``inherit:`` parent (path relative to the working directory) and merges the child
    over it; ``merge_config`` merges nested maps into its first argument in place;
    ``set_global_config`` updates the module dict's top level."""
    mod = types.ModuleType("mast3r_slam.config")
    mod.config = {}

    def merge_config(d1: dict, d2: dict) -> dict:
        for k, v in d2.items():
            if isinstance(v, dict):
                merge_config(d1.setdefault(k, {}), v)
            else:
                d1[k] = v
        return d1

    def set_global_config(cfg: dict) -> dict:
        mod.config.update(cfg)
        return mod.config

    def load_config(path: str = "config/base.yaml", is_parent: bool = False) -> Any:
        with open(path) as f:
            cfg = yaml.safe_load(f)
        parent = load_config(cfg["inherit"], is_parent=True) if cfg.get("inherit") else {}
        cfg = merge_config(parent, cfg)
        if is_parent:
            return cfg
        set_global_config(cfg)

    mod.merge_config, mod.set_global_config, mod.load_config = merge_config, set_global_config, load_config
    return mod


BASE = {  # the top-level sections of upstream config/base.yaml, a few values each (not its text)
    "use_calib": False, "single_thread": False,
    "dataset": {"subsample": 1, "img_downsample": 1, "center_principle_point": True},
    "tracking": {"Q_conf": 1.5, "min_match_frac": 0.05, "filtering_mode": "weighted_pointmap"},
    "local_opt": {"min_match_frac": 0.1, "Q_conf": 1.5},
    "retrieval": {"k": 3, "min_thresh": 5e-3},
    "reloc": {"min_match_frac": 0.3, "strict": True},
}


def checkout(tmp_path: Path) -> Path:
    """A clone's layout: ``mast3r_slam/`` (installed editable) beside ``config/base.yaml``."""
    (tmp_path / "mast3r_slam").mkdir(parents=True)
    (tmp_path / "mast3r_slam" / "__init__.py").write_text("")
    (tmp_path / "config").mkdir()
    (tmp_path / "config" / "base.yaml").write_text(yaml.safe_dump(BASE))
    return tmp_path


class Sim3:
    """lietorch Sim3 as far as the adapter touches it: ``data`` = (t, q xyzw, s), ``Identity``."""

    def __init__(self, data: np.ndarray):
        self.data = np.asarray(data, np.float64).reshape(1, 8)

    @classmethod
    def Identity(cls, n: int, device: str = "cpu") -> Sim3:
        return cls(np.array([0, 0, 0, 0, 0, 0, 1, 1.0]))


class Frame:
    """mast3r_slam/frame.py ``Frame``: ``update_pointmap`` in ``weighted_pointmap`` mode keeps the
    confidence-weighted mean point and the *summed* confidence C, counting N; ``get_average_conf``
    is C/N."""

    def __init__(self, frame_id: int, T_WC: Sim3):
        self.frame_id, self.T_WC = frame_id, T_WC
        self.X_canon: np.ndarray | None = None
        self.C: np.ndarray | None = None
        self.N = 0

    def update_pointmap(self, X: np.ndarray, C: np.ndarray) -> None:
        if self.N == 0:
            self.X_canon, self.C, self.N = X.copy(), C.copy(), 1
            return
        self.X_canon = (self.C * self.X_canon + C * X) / (self.C + C)
        self.C = self.C + C
        self.N += 1

    def get_average_conf(self) -> np.ndarray | None:
        return self.C / self.N if self.C is not None else None


class SharedKeyframes:
    """mast3r_slam/frame.py ``SharedKeyframes``: ``__setitem__`` (and so ``append``) stores a whole
    frame and sets ``is_dirty``; ``update_T_WCs`` writes poses only and does *not*;
    ``get_dirty_idx`` returns the dirty indices and clears them; ``T_WC`` is the raw pose buffer."""

    def __init__(self, manager: Any, h: int, w: int, buffer: int = 16):
        self.h, self.w, self.n = h, w, 0
        self.T_WC = np.zeros((buffer, 1, 8))
        self.X = np.zeros((buffer, h * w, 3), np.float32)
        self.C = np.zeros((buffer, h * w, 1), np.float32)
        self.N = np.zeros(buffer, np.int64)
        self.fid = np.zeros(buffer, np.int64)
        self.is_dirty = np.zeros(buffer, bool)

    def __getitem__(self, i: int) -> Frame:
        f = Frame(int(self.fid[i]), Sim3(self.T_WC[i].copy()))
        f.X_canon, f.C, f.N = self.X[i].copy(), self.C[i].copy(), int(self.N[i])
        return f

    def __setitem__(self, i: int, f: Frame) -> None:
        self.n = max(self.n, i + 1)
        self.T_WC[i], self.X[i], self.C[i], self.N[i], self.fid[i] = f.T_WC.data, f.X_canon, f.C, f.N, f.frame_id
        self.is_dirty[i] = True

    def __len__(self) -> int:
        return self.n

    def append(self, f: Frame) -> None:
        self[self.n] = f

    def pop_last(self) -> None:
        self.n -= 1

    def last_keyframe(self) -> Frame | None:
        return self[self.n - 1] if self.n else None

    def update_T_WCs(self, T_WCs: np.ndarray, idx: list[int]) -> None:
        self.T_WC[idx] = np.asarray(T_WCs).reshape(len(idx), 1, 8)

    def get_dirty_idx(self) -> np.ndarray:
        idx = np.flatnonzero(self.is_dirty)
        self.is_dirty[:] = False
        return idx


def make_tracker_module(script: list[str], step: np.ndarray) -> types.ModuleType:
    """mast3r_slam/tracker.py: ``FrameTracker.track(frame)`` calls the module-level
    ``mast3r_match_asymmetric(model, frame, keyframe, idx_i2j_init=...)`` (imported by name), fuses
    the frame's own pointmap, and either gives up early — ``(False, [], True)``: too few matches,
    relocalise — or sets the frame's pose, fuses the keyframe's pointmap and writes the keyframe
    back with ``keyframes[len - 1] = keyframe`` (marking it dirty), answering ``(new_kf, info, False)``."""
    mod = types.ModuleType("mast3r_slam.tracker")

    def mast3r_match_asymmetric(model: Any, frame: Frame, keyframe: Frame, idx_i2j_init: Any = None) -> tuple:
        n = keyframe.X_canon.shape[0]
        X = np.tile(np.array([0.0, 0.0, 2.0], np.float32), (n, 1))
        C = np.full((n, 1), 2.0, np.float32)
        return (np.arange(n)[None], np.ones((1, n, 1), bool), X, C, np.full((n, 1), 4.0), X, C, np.full((n, 1), 4.0))

    class FrameTracker:
        def __init__(self, model: Any, keyframes: SharedKeyframes, device: str):
            self.model, self.keyframes = model, keyframes
            self.guesses: list[np.ndarray] = []

        def track(self, frame: Frame) -> tuple:
            self.guesses.append(frame.T_WC.data.copy())
            kf = self.keyframes.last_keyframe()
            _, _, Xff, Cff, _, Xkf, Ckf, _ = mod.mast3r_match_asymmetric(self.model, frame, kf, idx_i2j_init=None)
            frame.update_pointmap(Xff, Cff)
            outcome = script.pop(0)
            if outcome == "lost":
                return False, [], True
            frame.T_WC = Sim3(frame.T_WC.data + step)
            kf.update_pointmap(Xkf, Ckf)
            self.keyframes[len(self.keyframes) - 1] = kf
            return outcome == "new", [], False

    mod.mast3r_match_asymmetric, mod.FrameTracker = mast3r_match_asymmetric, FrameTracker
    return mod


class FactorGraph:
    """mast3r_slam/global_opt.py ``FactorGraph``: ``add_factors(ii, jj, min_match_frac,
    is_reloc=False)`` answers whether the edges were accepted; ``solve_GN_rays`` writes the
    optimised poses through ``keyframes.update_T_WCs`` (so they are *not* marked dirty)."""

    def __init__(self, model: Any, keyframes: SharedKeyframes, K: Any, device: str):
        self.keyframes = keyframes
        self.calls: list[tuple] = []
        self.accept = True
        self.moves: dict[int, np.ndarray] = {}  # poses the next solve will write

    def add_factors(self, ii: list[int], jj: list[int], min_match_frac: float, is_reloc: bool = False) -> bool:
        self.calls.append((list(ii), list(jj), min_match_frac, is_reloc))
        return self.accept

    def solve_GN_rays(self) -> None:
        if self.moves:
            idx = sorted(self.moves)
            self.keyframes.update_T_WCs(np.stack([self.moves[i] for i in idx]), idx)
            self.moves = {}


class Retriever:
    """mast3r_slam/retrieval_database.py ``RetrievalDatabase.update(frame, add_after_query, k,
    min_thresh)``: the indices of up to k similar keyframes already in the database."""

    def __init__(self) -> None:
        self.answers: list[list[int]] = []
        self.calls: list[bool] = []

    def update(self, frame: Frame, add_after_query: bool, k: int, min_thresh: float = 0.0) -> list[int]:
        self.calls.append(add_after_query)
        return self.answers.pop(0) if self.answers else []


def make_slam(script: list[str], subsample: int = 1, update_every: int = 2) -> tuple[Mast3rSlam, dict]:
    cfg = fake_config_module()
    cfg.config.update(BASE)
    cfg.merge_config(cfg.config, {"dataset": {"subsample": subsample}})
    step = np.array([[0.1, 0, 0, 0, 0, 0, 0, 0]])
    created: list[Sim3] = []

    def create_frame(i: int, img: np.ndarray, T_WC: Sim3, img_size: int = 512, device: str = "cuda:0") -> Frame:
        """mast3r_slam/frame.py ``create_frame``: a new frame that starts at the pose it is given."""
        created.append(T_WC)
        return Frame(i, T_WC)

    def mast3r_inference_mono(model: Any, frame: Frame) -> tuple[np.ndarray, np.ndarray]:
        """mast3r_slam/mast3r_utils.py: the frame's pointmap and confidence from one image."""
        n = 384 * 512
        return np.tile(np.array([0.0, 0.0, 1.0], np.float32), (n, 1)), np.full((n, 1), 3.0, np.float32)

    m = {
        "torch": types.SimpleNamespace(inference_mode=contextlib.nullcontext),
        "lietorch": types.SimpleNamespace(Sim3=Sim3),
        "mast3r_slam.config": cfg,
        "mast3r_slam.frame": types.SimpleNamespace(create_frame=create_frame, SharedKeyframes=SharedKeyframes),
        "mast3r_slam.tracker": make_tracker_module(script, step),
        "mast3r_slam.mast3r_utils": types.SimpleNamespace(mast3r_inference_mono=mast3r_inference_mono),
        "mast3r_slam.global_opt": types.SimpleNamespace(FactorGraph=FactorGraph),
    }
    retriever = Retriever()
    slam = Mast3rSlam(m, "model", retriever, lambda rgb: np.full(rgb.shape[:2], 7, np.uint16),
                      SlamParams(device="cpu", update_every=update_every))
    return slam, {"created": created, "retriever": retriever}


def image() -> Image:
    return Image(encoding="rgb8", width=64, height=48, data=np.zeros((48, 64, 3), np.uint8))


def kinds(frames: list) -> list[tuple[str, int]]:
    return [(f.kind, f.keyframe_id) for f in frames]


# -- config -----------------------------------------------------------------------------------------


def test_the_config_is_always_loaded_from_the_checkout_with_the_authors_overrides(tmp_path: Path) -> None:
    root = checkout(tmp_path)
    pkg = types.SimpleNamespace(__file__=str(root / "mast3r_slam" / "__init__.py"))
    path = checkout_config(pkg)
    assert path == (root / "config" / "base.yaml").resolve()
    cfg_mod = fake_config_module()
    shared = cfg_mod.config  # what FrameTracker / create_frame imported by name
    cfg = load_config(cfg_mod, path, AUTHORS_OVERRIDES)
    assert cfg is shared  # filled in place, never rebound
    assert cfg["dataset"] == {"subsample": 10, "img_downsample": 1, "center_principle_point": True}
    assert cfg["tracking"]["filtering_mode"] == "weighted_pointmap" and cfg["retrieval"]["k"] == 3


def test_a_config_of_ones_own_inherits_relative_to_the_checkout(tmp_path: Path) -> None:
    root = checkout(tmp_path)
    (root / "config" / "mine.yaml").write_text('inherit: "config/base.yaml"\nreloc:\n  strict: false\n')
    cwd = os.getcwd()
    cfg = load_config(fake_config_module(), root / "config" / "mine.yaml", {})
    assert os.getcwd() == cwd
    assert cfg["reloc"] == {"min_match_frac": 0.3, "strict": False} and cfg["dataset"]["subsample"] == 1


def test_a_config_without_the_sections_or_calibrated_is_refused(tmp_path: Path) -> None:
    (tmp_path / "bad.yaml").write_text("use_calib: false\ndataset: {subsample: 1}\n")
    with pytest.raises(MissingBackend, match="lacks single_thread, tracking"):
        load_config(fake_config_module(), tmp_path / "bad.yaml")
    root = checkout(tmp_path / "c")
    with pytest.raises(MissingBackend, match="use_calib"):
        load_config(fake_config_module(), root / "config" / "base.yaml", {"use_calib": True})
    with pytest.raises(MissingBackend, match="missing"):
        load_config(fake_config_module(), tmp_path / "nowhere.yaml")


def test_startup_check_names_every_missing_piece_in_one_line(tmp_path: Path) -> None:
    root = checkout(tmp_path / "clone")
    torch = types.SimpleNamespace(cuda=types.SimpleNamespace(is_available=lambda: False))
    mods = {name: types.SimpleNamespace() for name in REQUIRED}
    mods["torch"], mods["mast3r_slam"] = torch, types.SimpleNamespace(__file__=str(root / "mast3r_slam" / "x.py"))
    ckpt = tmp_path / "ckpt"
    ckpt.mkdir()
    (ckpt / CHECKPOINT).write_bytes(b"x")
    with pytest.raises(MissingBackend) as err:
        startup_check(ckpt, None, "cuda:0", importer=mods.__getitem__)
    text = str(err.value)
    assert "\n" not in text and RETRIEVER in text and CODEBOOK in text and "no CUDA device" in text
    assert CHECKPOINT + "," not in text and "config" not in text.split("INSTALL")[0].replace(CODEBOOK, "")
    for name in (RETRIEVER, CODEBOOK):
        (ckpt / name).write_bytes(b"x")
    with pytest.raises(MissingBackend, match=r"config .*nowhere.yaml missing; no CUDA device"):
        startup_check(ckpt, tmp_path / "nowhere.yaml", "cuda:0", importer=mods.__getitem__)
    torch.cuda.is_available = lambda: True
    got, path = startup_check(ckpt, None, "cuda:0", importer=mods.__getitem__)
    assert path == (root / "config" / "base.yaml").resolve() and got["torch"] is torch

    def no_lietorch(name: str) -> Any:
        if name == "lietorch":
            raise ImportError("no", name="lietorch")
        return mods[name]

    with pytest.raises(MissingBackend, match="cannot import lietorch") as err:
        startup_check(ckpt, None, "cuda:0", importer=no_lietorch)
    assert "princeton-vl/lietorch" in str(err.value)


# -- conventions ------------------------------------------------------------------------------------


def test_sim3_fields_split_as_upstream_as_se3() -> None:
    """mast3r_slam/lietorch_utils.py ``as_SE3``: ``data.split([3, 4, 1])`` → t, q (xyzw), s."""
    data = np.array([1.0, -2.0, 0.5, 0.0, np.sin(0.3), 0.0, np.cos(0.3), 1.7])
    t, _q, s = np.split(data, [3, 7])
    T, scale = sim3_pose(data)
    np.testing.assert_allclose(T[:3, 3], t)
    assert scale == s[0]
    # q = (0, sin 0.3, 0, cos 0.3): a rotation of 0.6 rad about y
    np.testing.assert_allclose(T[:3, :3], [[np.cos(0.6), 0, np.sin(0.6)], [0, 1, 0], [-np.sin(0.6), 0, np.cos(0.6)]],
                               atol=1e-12)


def test_messages_carry_the_average_confidence_thresholded_at_1_5() -> None:
    """Frame.get_average_conf (C/N) after weighted_pointmap fusion, not the running sum C."""
    f = Frame(0, Sim3.Identity(1))
    n = 6
    X = np.tile([0.0, 0.0, 1.0], (n, 1))
    f.update_pointmap(X, np.array([[1.2], [1.4], [2.0], [3.0], [1.0], [5.0]]))
    f.update_pointmap(X, np.array([[1.2], [1.4], [1.0], [3.0], [2.5], [5.0]]))
    assert f.C[0, 0] == pytest.approx(2.4)  # the sum would pass any threshold
    msg = keyframe_message(SlamFrame(f.X_canon, f.get_average_conf(), f.T_WC.data, np.zeros(n), (2, 3), 0), 1,
                           c_conf=C_CONF, kind="keyframe_new")
    np.testing.assert_allclose(msg.confidence.reshape(-1), [0, 0, 1.5, 3.0, 1.75, 5.0])
    assert C_CONF == 1.5 and msg.kind == "keyframe_new"


# -- the loop ---------------------------------------------------------------------------------------


def test_keyframes_new_updates_and_tracking_frames() -> None:
    slam, _fx = make_slam(["ok", "ok", "new", "ok"], update_every=2)
    out = slam.process(image(), None, 1)
    assert kinds(out) == [("keyframe_new", 0)]
    assert out[0].points.shape == (384, 512, 3)
    np.testing.assert_allclose(out[0].confidence, 3.0)  # C/N of the mono inference
    out = slam.process(image(), None, 2)  # tracked; kf 0 refined (dirty) but not due yet
    assert kinds(out) == [("tracking", 0)]
    out = slam.process(image(), None, 3)  # second tracked frame: the refined kf 0 is due
    assert kinds(out) == [("tracking", 0), ("keyframe_update", 0)]
    # refined twice more (N = 3): sum C = 3 + 2 + 2, the average is 7/3
    np.testing.assert_allclose(out[1].confidence, 7 / 3, rtol=1e-6)
    out = slam.process(image(), None, 4)  # a new keyframe: kf 0's final state, then kf 1
    assert kinds(out) == [("tracking", 0), ("keyframe_update", 0), ("keyframe_new", 1)]
    g = slam.graph
    assert g.calls[-1] == ([0], [1], BASE["local_opt"]["min_match_frac"], False)
    # a loop closure re-poses kf 0 through update_T_WCs: not dirty, found by comparing poses
    g.moves = {0: np.array([[0.0, 0.3, 0, 0, 0, 0, 1, 1]])}
    g.solve_GN_rays()
    assert slam.keyframes.get_dirty_idx().size == 0
    slam.keyframes.is_dirty[:] = False
    out = slam.process(image(), None, 5)
    assert ("keyframe_update", 0) in kinds(out)
    upd = next(f for f in out if f.keyframe_id == 0 and f.kind == "keyframe_update")
    np.testing.assert_allclose(upd.T_WC[:3, 3], [0.0, 0.3, 0.0])


def test_the_initial_guess_is_the_last_tracked_frame_not_the_keyframe() -> None:
    slam, _fx = make_slam(["ok", "ok"])
    for stamp in range(3):
        slam.process(image(), None, stamp)
    guesses = slam.tracker.guesses
    # frame 1 starts from frame 0's pose (identity); frame 2 from frame 1's tracked pose (+0.1 in x),
    # while the only keyframe is still at identity
    assert guesses[0][0, 0] == pytest.approx(0.0) and guesses[1][0, 0] == pytest.approx(0.1)
    assert slam.keyframes.T_WC[0, 0, 0] == pytest.approx(0.0)


def test_tracking_loss_switches_to_relocalisation_until_a_keyframe_accepts() -> None:
    slam, fx = make_slam(["ok", "lost", "ok"])
    retriever = fx["retriever"]
    slam.process(image(), None, 0)
    slam.process(image(), None, 1)
    slam.keyframes.T_WC[0] = [[0.5, 0, 0, 0, 0, 0, 1, 1]]  # where kf 0 sits now (after optimisation)
    slam.published[0] = slam.keyframes.T_WC[0].reshape(-1).copy()
    assert slam.process(image(), None, 2) == [] and slam.mode == "reloc"  # lost: nothing published
    retriever.answers = [[]]  # no candidate: stays lost, nothing appended
    assert slam.process(image(), None, 3) == [] and slam.mode == "reloc" and len(slam.keyframes) == 1
    slam.graph.accept = False
    retriever.answers = [[0]]  # a candidate whose factors fail: the frame is popped again
    assert slam.process(image(), None, 4) == [] and len(slam.keyframes) == 1
    slam.graph.accept = True
    retriever.answers = [[0]]
    out = slam.process(image(), None, 5)
    assert kinds(out) == [("keyframe_new", 1)] and slam.mode == "tracking" and slam.relocalisations == 1
    assert slam.graph.calls[-1] == ([1], [0], BASE["reloc"]["min_match_frac"], True)  # strict
    assert retriever.calls[-2:] == [False, True]  # query without adding, then add on success
    np.testing.assert_allclose(out[0].T_WC[:3, 3], [0.5, 0, 0])  # starts at the candidate's pose
    assert kinds(slam.process(image(), None, 6))[0] == ("tracking", 1)


def test_subsampling_keeps_every_nth_image() -> None:
    slam, _fx = make_slam(["ok"] * 3, subsample=3)
    produced = [bool(slam.process(image(), None, i)) for i in range(7)]
    assert produced == [True, False, False, True, False, False, True] and slam.i == 3


def test_slam_world_is_anchored_where_odometry_put_the_first_camera() -> None:
    slam, _ = make_slam(["ok"])
    A = np.eye(4)
    A[:3, :3] = [[0, 0, 1], [-1, 0, 0], [0, -1, 0]]  # optical axes in a z-up map
    A[:3, 3] = (2.0, 1.0, 0.1)
    stamps: list[int] = []
    slam.anchor = lambda stamp: (stamps.append(stamp), A)[1]
    (first,) = slam.process(image(), None, 42)
    assert stamps == [42]
    np.testing.assert_allclose(first.T_WC, A)
    out = slam.process(image(), None, 43)  # tracked 0.1 along SLAM's x (the camera's right)
    np.testing.assert_allclose(out[0].T_WC[:3, 3], [2.0, 0.9, 0.1], atol=1e-12)
    assert stamps == [42]  # anchored once
