"""Camera calibration files: ROS ``camera_info`` YAML and OpenCV ``FileStorage`` YAML.

Pure: text in, a :class:`Calibration` out (no device, no network). Two formats are read:

* **ROS camera_info YAML** — what ``camera_calibration`` writes and ``camera_info_manager`` loads
  (ros-perception/image_common, ``camera_calibration_parsers/src/parse_yml.cpp``,
  ``readCalibrationYml``): ``image_width``, ``image_height``, ``camera_matrix``,
  ``distortion_model``, ``distortion_coefficients``, ``rectification_matrix`` and
  ``projection_matrix``, each matrix a map ``{rows, cols, data}`` in row-major order. Upstream
  requires R and P; here they are optional (identity and ``[K | 0]``), as hand-written files lack
  them. A missing ``distortion_model`` means ``plumb_bob``, as upstream assumes.
* **OpenCV FileStorage YAML** — what ``cv::FileStorage`` writes (opencv/opencv,
  ``modules/core/src/persistence_yml.cpp``): a ``%YAML:1.0`` first line (not valid YAML 1.1, so it
  is dropped before parsing) and matrices tagged ``!!opencv-matrix`` with ``rows``, ``cols``,
  ``dt`` and ``data``. Keys as OpenCV's calibration sample writes them (``camera_matrix``,
  ``distortion_coefficients``, ``image_width``, ``image_height``) or the other common spellings
  (``cameraMatrix``/``K``, ``distCoeffs``/``dist_coeffs``/``D``). The distortion model is the
  pinhole one of ``cv::calibrateCamera`` (4, 5, 8, 12 or 14 coefficients) unless a
  ``distortion_model`` key says ``fisheye``/``equidistant`` (``cv::fisheye``, 4 coefficients).

Distortion models (OpenCV's conventions; ROS names): ``plumb_bob`` (k1, k2, p1, p2[, k3]),
``rational_polynomial`` (k1, k2, p1, p2, k3, k4, k5, k6) and ``equidistant`` (k1..k4 of the fisheye
model). The thin-prism and tilt terms of 12/14-coefficient OpenCV files are refused unless zero.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml

DistortionModel = Literal["plumb_bob", "rational_polynomial", "equidistant"]

_MODEL_NAMES: dict[str, DistortionModel] = {
    "plumb_bob": "plumb_bob", "radtan": "plumb_bob", "pinhole": "plumb_bob", "brown": "plumb_bob",
    "rational_polynomial": "rational_polynomial",
    "equidistant": "equidistant", "fisheye": "equidistant", "kannala_brandt": "equidistant",
}


class CalibrationError(ValueError):
    """A calibration file that cannot be used: names the file, the key and what is wrong."""


@dataclass(frozen=True)
class Calibration:
    """A calibrated camera: raw-image intrinsics ``K``, distortion, and the rectified image's
    projection ``P`` (the pinhole intrinsics of the undistorted image; ``K`` unless the file says)."""

    width: int
    height: int
    K: np.ndarray
    D: np.ndarray
    model: DistortionModel = "plumb_bob"
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    P: np.ndarray | None = None
    name: str = ""

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=float)
        if K.shape != (3, 3) or not np.all(np.isfinite(K)):
            raise CalibrationError("camera matrix must be 3x3 and finite")
        if K[0, 0] <= 0 or K[1, 1] <= 0 or abs(K[2, 2] - 1.0) > 1e-9 or np.any(K[1:, 0] != 0) or K[2, 1] != 0:
            raise CalibrationError(f"camera matrix {K.tolist()} is not [[fx, s, cx], [0, fy, cy], [0, 0, 1]] "
                                   "with fx, fy > 0")
        D = np.asarray(self.D, dtype=float).reshape(-1)
        if not np.all(np.isfinite(D)):
            raise CalibrationError("distortion coefficients must be finite")
        need = {"plumb_bob": (0, 4, 5, 8), "rational_polynomial": (0, 4, 5, 8), "equidistant": (0, 4)}[self.model]
        if D.size not in need:
            raise CalibrationError(f"distortion model {self.model} takes {', '.join(map(str, need[1:]))} "
                                   f"coefficients, the file has {D.size}")
        R = np.asarray(self.R, dtype=float)
        if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) <= 0:
            raise CalibrationError("rectification matrix must be a 3x3 rotation")
        P = K if self.P is None else np.asarray(self.P, dtype=float)
        P = P[:, :3] if P.shape == (3, 4) else P
        if P.shape != (3, 3) or not np.all(np.isfinite(P)) or P[0, 0] <= 0 or P[1, 1] <= 0:
            raise CalibrationError("projection matrix must be 3x4 (or 3x3) with fx, fy > 0")
        if self.width <= 0 or self.height <= 0:
            raise CalibrationError(f"image size {self.width}x{self.height} must be positive")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "D", D)
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "P", P)

    @property
    def distorted(self) -> bool:
        """Whether raw pixels differ from the pinhole image (distortion or rectification)."""
        return bool(np.any(self.D != 0)) or not np.allclose(self.R, np.eye(3)) or not np.allclose(self.P, self.K)

    @property
    def intrinsics(self) -> tuple[float, float, float, float]:
        """(fx, fy, cx, cy) of the undistorted image: the pinhole model perception is handed."""
        P = self.P
        assert P is not None
        return float(P[0, 0]), float(P[1, 1]), float(P[0, 2]), float(P[1, 2])

    @property
    def raw_intrinsics(self) -> tuple[float, float, float, float]:
        return float(self.K[0, 0]), float(self.K[1, 1]), float(self.K[0, 2]), float(self.K[1, 2])

    def scaled(self, width: int, height: int) -> Calibration:
        """The same camera at another resolution of the same aspect ratio (a V4L2 mode other than
        the one calibrated): focal lengths and principal point scale; distortion does not (it acts
        on normalised coordinates). Pixel centres at integer coordinates: c' = (c + 0.5)·s − 0.5."""
        if (width, height) == (self.width, self.height):
            return self
        sx, sy = width / self.width, height / self.height
        if not math.isclose(sx, sy, rel_tol=0.01):
            raise CalibrationError(f"calibrated at {self.width}x{self.height}, the camera gives {width}x{height}: "
                                   "another aspect ratio (a crop) cannot be derived; calibrate this mode")

        def scale(M: np.ndarray) -> np.ndarray:
            M = M.copy()
            M[0, :] *= sx
            M[1, :] *= sy
            M[0, 2] += 0.5 * sx - 0.5
            M[1, 2] += 0.5 * sy - 0.5
            return M

        assert self.P is not None
        return Calibration(width, height, scale(self.K), self.D, self.model, self.R, scale(self.P), self.name)


# -- parsing ------------------------------------------------------------------------------------

class _OpenCvLoader(yaml.SafeLoader):
    """A safe loader that also knows OpenCV's ``!!opencv-matrix`` tag (a map, kept as a map)."""


def _opencv_matrix(loader: yaml.SafeLoader, node: yaml.Node) -> dict[str, Any]:
    if not isinstance(node, yaml.MappingNode):
        raise yaml.constructor.ConstructorError(None, None, "!!opencv-matrix must be a map", node.start_mark)
    return {**loader.construct_mapping(node, deep=True), "__opencv__": True}


for _tag in ("tag:yaml.org,2002:opencv-matrix", "tag:yaml.org,2002:opencv-nd-matrix"):
    _OpenCvLoader.add_constructor(_tag, _opencv_matrix)


def _matrix(doc: dict[str, Any], keys: tuple[str, ...], shape: tuple[int, int] | None, what: str,
            required: bool = True) -> np.ndarray | None:
    key = next((k for k in keys if k in doc), None)
    if key is None:
        if required:
            raise CalibrationError(f"no {what} (key {' or '.join(map(repr, keys))})")
        return None
    node = doc[key]
    if isinstance(node, dict):
        if "data" not in node:
            raise CalibrationError(f"{key!r} has no 'data'")
        data, rows, cols = node["data"], node.get("rows"), node.get("cols")
    else:  # a bare list (some hand-written files)
        data, rows, cols = node, None, None
    try:
        arr = np.asarray(data, dtype=float).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"{key!r}: data must be a list of numbers ({exc})") from None
    if rows is not None and cols is not None:
        if not isinstance(rows, int) or not isinstance(cols, int) or rows * cols != arr.size:
            raise CalibrationError(f"{key!r}: rows x cols = {rows} x {cols} but data has {arr.size} numbers")
    if shape is not None:
        if arr.size != shape[0] * shape[1]:
            raise CalibrationError(f"{key!r}: {what} needs {shape[0]}x{shape[1]} numbers, has {arr.size}")
        arr = arr.reshape(shape)
    if not np.all(np.isfinite(arr)):
        raise CalibrationError(f"{key!r}: {what} has NaN or Inf")
    return arr


def _size(doc: dict[str, Any], keys: tuple[str, ...], what: str) -> int:
    key = next((k for k in keys if k in doc), None)
    if key is None:
        raise CalibrationError(f"no image {what} (key {' or '.join(map(repr, keys))})")
    value = doc[key]
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise CalibrationError(f"{key!r} must be a positive integer, got {value!r}")
    return value


def _model(name: Any) -> DistortionModel:
    model = _MODEL_NAMES.get(str(name).strip().lower())
    if model is None:
        raise CalibrationError(f"distortion model {name!r} is not supported; known: {', '.join(sorted(_MODEL_NAMES))}")
    return model


def _opencv_coefficients(D: np.ndarray, model: DistortionModel) -> np.ndarray:
    """OpenCV's pinhole vector is (k1, k2, p1, p2[, k3[, k4, k5, k6[, s1..s4[, tx, ty]]]])."""
    if model == "equidistant" or D.size in (0, 4, 5, 8):
        return D
    if D.size in (12, 14):
        if np.any(D[8:] != 0):
            raise CalibrationError("thin-prism / tilt distortion terms (coefficients 9-14) are not supported")
        return D[:8]
    raise CalibrationError(f"an OpenCV distortion vector has 4, 5, 8, 12 or 14 coefficients, the file has {D.size}")


def parse_calibration(text: str, source: str = "calibration") -> Calibration:
    """A :class:`Calibration` from the text of a ROS camera_info or OpenCV FileStorage YAML file."""
    lines = text.splitlines()
    opencv = bool(lines) and lines[0].lstrip().startswith("%YAML:")
    if opencv:  # OpenCV's header is "%YAML:1.0", which no YAML 1.1 parser accepts
        text = "\n".join(lines[1:])
    try:
        doc = yaml.load(text, Loader=_OpenCvLoader)  # a SafeLoader subclass
    except yaml.YAMLError as exc:
        raise CalibrationError(f"{source}: not YAML ({exc})") from None
    if not isinstance(doc, dict):
        raise CalibrationError(f"{source}: the top level must be a map")
    opencv = opencv or any(isinstance(v, dict) and v.get("__opencv__") for v in doc.values())
    try:
        width = _size(doc, ("image_width", "width", "imageWidth"), "width")
        height = _size(doc, ("image_height", "height", "imageHeight"), "height")
        if opencv:
            K = _matrix(doc, ("camera_matrix", "cameraMatrix", "K"), (3, 3), "camera matrix")
            D = _matrix(doc, ("distortion_coefficients", "distCoeffs", "dist_coeffs", "D"), None,
                        "distortion coefficients", required=False)
            model = _model(doc.get("distortion_model", "plumb_bob"))
            D = _opencv_coefficients(np.zeros(0) if D is None else D.reshape(-1), model)
            R = _matrix(doc, ("rectification_matrix", "R"), (3, 3), "rectification matrix", required=False)
            P = _matrix(doc, ("projection_matrix", "P", "new_camera_matrix"), None, "projection matrix",
                        required=False)
        else:
            K = _matrix(doc, ("camera_matrix",), (3, 3), "camera matrix")
            D = _matrix(doc, ("distortion_coefficients",), None, "distortion coefficients", required=False)
            model = _model(doc.get("distortion_model", "plumb_bob"))
            D = np.zeros(0) if D is None else D.reshape(-1)
            if model == "plumb_bob" and D.size == 8:  # camera_calibration writes 8 for rational_polynomial
                model = "rational_polynomial"
            R = _matrix(doc, ("rectification_matrix",), (3, 3), "rectification matrix", required=False)
            P = _matrix(doc, ("projection_matrix",), (3, 4), "projection matrix", required=False)
        if P is not None and P.size not in (9, 12):
            raise CalibrationError(f"projection matrix must be 3x3 or 3x4, has {P.size} numbers")
        if P is not None:
            P = P.reshape(3, -1)
        if P is not None and P.shape == (3, 4) and np.any(P[:, 3] != 0):
            raise CalibrationError("projection matrix has a stereo baseline (P[:, 3] != 0): use the left camera's")
        assert K is not None
        return Calibration(width, height, K, D, model, np.eye(3) if R is None else R, P,
                           str(doc.get("camera_name", "")))
    except CalibrationError as exc:
        raise CalibrationError(f"{source}: {exc}") from None


def load_calibration(path: str | Path) -> Calibration:
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"calibration file {p} does not exist")
    return parse_calibration(p.read_text(), str(p))
