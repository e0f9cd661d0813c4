"""The calibration record and its file format (OpenCV FileStorage YAML, see
docs/reference/calibration-format.md).

Lengths are metres (the board's square size is given in metres), pixels are of the full-size
image. ``f, B, cx, cy`` are those of the rectified pair: ``f = P1[0,0]``, ``cx = P1[0,2]``,
``cy = P1[1,2]``, ``B = -P2[0,3] / P2[0,0]``.
"""

from __future__ import annotations

import base64
import binascii
import dataclasses
import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from vbfe.acquire.image_size import size_mismatch
from vbfe.common.errors import CalibrationError
from vbfe.common.files import write_bytes_atomic

FORMAT_VERSION = 1

# name -> allowed shapes (None: any length vector)
_MATRICES: dict[str, tuple[tuple[int, ...], ...]] = {
    "K1": ((3, 3),),
    "K2": ((3, 3),),
    "R": ((3, 3),),
    "T": ((3,),),
    "R1": ((3, 3),),
    "R2": ((3, 3),),
    "P1": ((3, 4),),
    "P2": ((3, 4),),
    "Q": ((4, 4),),
    "D1": ((4,), (5,), (8,), (12,), (14,)),
    "D2": ((4,), (5,), (8,), (12,), (14,)),
}
_OPTIONAL_MATRICES: dict[str, tuple[tuple[int, ...], ...]] = {
    "K_proj": ((3, 3),),
    "D_proj": ((4,), (5,), (8,), (12,), (14,)),
    "R_proj": ((3, 3),),
    "T_proj": ((3,),),
    "color_mixing": ((3, 3),),
    "color_offset": ((3,),),
    "per_view_rms_px": ((-1, 3),),
}
_VECTORS = {"T", "D1", "D2", "D_proj", "T_proj", "color_offset"}


_INFO_NODE = "info"  # the info dict as a YAML map (see _write_info)
# files written before the YAML map: base64 of the JSON text, or raw JSON, in pieces
_OLD_INFO_NODES = ("info_json_base64", "info_json")
_KEY = re.compile(r"[A-Za-z_][A-Za-z0-9_\- ]*")  # what FileStorage takes as a map key
_PLAIN_WORDS = {"null", "~", ".nan", ".inf", "-.inf", "true", "false", "yes", "no"}


def reprojection_matrix(P1: np.ndarray, P2: np.ndarray) -> np.ndarray:
    """The disparity-to-depth matrix ``Q`` of a rectified pair with projection matrices ``P1,
    P2``: OpenCV's (``stereoRectify``), its y row scaled by ``fx/fy`` so that
    ``Y = (v - cy)·z/fy`` also for unequal focal lengths (1 for OpenCV's own rectification)."""
    f, aspect = P1[0, 0], P1[0, 0] / P1[1, 1]
    tx = P2[0, 3] / P2[0, 0]  # −B, in metres
    return np.array(
        [
            [1.0, 0.0, 0.0, -P1[0, 2]],
            [0.0, aspect, 0.0, -P1[1, 2] * aspect],
            [0.0, 0.0, 0.0, f],
            [0.0, 0.0, -1.0 / tx, (P1[0, 2] - P2[0, 2]) / tx],
        ]
    )


@dataclass
class Calibration:
    """Stereo endoscope calibration (plus optional projector and colour correction).

    Made by ``vbfe calibrate stereo`` (:func:`vbfe.calib.stereo.calibrate_stereo`), read with
    :meth:`load` (or :func:`load_calibration`, which also takes a session) and written with
    :meth:`save`. The rectified pair's geometry is :attr:`f`, :attr:`B`, :attr:`cx`,
    :attr:`cy`, :attr:`disparity_offset` and ``Q``.

    :param K1: left camera matrix (3×3, px). ``D1``: its distortion coefficients.
    :param K2: right camera matrix. ``D2``: its distortion coefficients.
    :param R: rotation from left-camera to right-camera coordinates; ``T`` the translation
        (m; OpenCV ``stereoCalibrate`` convention).
    :param R1: rectifying rotation of the left camera; ``R2`` of the right one.
    :param P1: rectified left projection matrix (3×4); ``P2`` the right one.
    :param Q: disparity-to-depth matrix (4×4, see :func:`reprojection_matrix`).
    :param image_size: ``(width, height)`` of one eye's images.
    :param info: JSON-able extras (board, per-view RMS, standard deviations, depth
        uncertainty, rejected corners, desynchronised views, ...).

    The optional fields hold RMS errors and the projector's intrinsics and pose (``R_proj,
    T_proj`` map left-camera coordinates to projector coordinates).

    :raises CalibrationError: a matrix of the wrong shape, NaN or infinite values, a
        non-positive image size, or a rectified right focal length that is not positive.
    """

    K1: np.ndarray
    D1: np.ndarray
    K2: np.ndarray
    D2: np.ndarray
    R: np.ndarray
    T: np.ndarray
    R1: np.ndarray
    R2: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    Q: np.ndarray
    image_size: tuple[int, int]  # (width, height) of one eye
    rms_left_px: float = float("nan")
    rms_right_px: float = float("nan")
    rms_stereo_px: float = float("nan")
    per_view_rms_px: np.ndarray | None = None  # (n_views, 3): left, right, stereo
    K_proj: np.ndarray | None = None
    D_proj: np.ndarray | None = None
    R_proj: np.ndarray | None = None
    T_proj: np.ndarray | None = None
    projector_size: tuple[int, int] | None = None
    rms_projector_px: float = float("nan")
    color_mixing: np.ndarray | None = None
    color_offset: np.ndarray | None = None
    info: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name, shapes in {**_MATRICES, **_OPTIONAL_MATRICES}.items():
            value = getattr(self, name)
            if value is None:
                continue
            arr = np.asarray(value, dtype=np.float64)
            if name in _VECTORS and arr.ndim == 2 and min(arr.shape) != 1:
                raise CalibrationError(
                    f"calibration field {name} is a {arr.shape} matrix, not a vector"
                )
            if name in _VECTORS:
                arr = arr.reshape(-1)
            if not any(_shape_ok(arr.shape, s) for s in shapes):
                raise CalibrationError(
                    f"calibration field {name} has shape {arr.shape}, expected "
                    f"{' or '.join(str(s).replace('-1', 'n') for s in shapes)}"
                )
            if name in _MATRICES or name in ("K_proj", "D_proj", "R_proj", "T_proj"):
                if not np.isfinite(arr).all():
                    raise CalibrationError(
                        f"calibration field {name} holds NaN or infinite "
                        "values; recalibrate with 'vbfe calibrate stereo'"
                    )
            setattr(self, name, arr)
        self.image_size = (int(self.image_size[0]), int(self.image_size[1]))
        if self.projector_size is not None:
            self.projector_size = (int(self.projector_size[0]), int(self.projector_size[1]))
        self._check_physical()

    def _check_physical(self) -> None:
        w, h = self.image_size
        if w <= 0 or h <= 0:
            raise CalibrationError(f"calibration image size {w}x{h} is not positive")
        for name in ("K1", "K2"):
            K = getattr(self, name)
            if K[0, 0] <= 0 or K[1, 1] <= 0:
                raise CalibrationError(f"calibration {name} has a focal length <= 0")
            if not (0 <= K[0, 2] < w and 0 <= K[1, 2] < h):
                raise CalibrationError(
                    f"calibration {name} puts the principal point "
                    f"({K[0, 2]:.1f}, {K[1, 2]:.1f}) outside the {w}x{h} "
                    "image; recalibrate"
                )
        if self.P2[0, 0] <= 0:  # a zero or impossible baseline is for the sanity gates to judge
            raise CalibrationError(
                f"the rectified right focal length P2[0,0] = {self.P2[0, 0]:.4g} px is not "
                "positive: the two eyes' geometry is inconsistent (the views' left and right "
                "images do not show the same board poses); check each pair is one moment of "
                "one rig and the board options match the board"
            )

    # --- the rectified pair -------------------------------------------------------------
    @property
    def f(self) -> float:
        """Focal length of the rectified pair (pixels)."""
        return float(self.P1[0, 0])

    @property
    def B(self) -> float:
        """Baseline of the rectified pair (metres)."""
        return float(-self.P2[0, 3] / self.P2[0, 0])

    @property
    def fy(self) -> float:
        """Vertical focal length of the rectified pair (pixels; ``f`` is the horizontal one)."""
        return float(self.P1[1, 1])

    @property
    def doffs(self) -> float:
        """Right minus left rectified principal point x (px; Middlebury's ``doffs``): a point at
        depth ``z`` has disparity ``d = f·B/z - doffs``; 0 after OpenCV's zero-disparity
        rectification."""
        return float(self.P2[0, 2] - self.P1[0, 2])

    @property
    def disparity_offset(self) -> float:
        """Disparity of a point at infinity (px; left minus right rectified principal point x,
        ``-doffs``): a point at depth ``z`` has disparity ``d = f·B/z + disparity_offset``."""
        return -self.doffs

    @classmethod
    def rectified(
        cls,
        fx: float,
        fy: float,
        baseline_m: float,
        cx: float,
        cy: float,
        image_size: tuple[int, int],
        doffs: float = 0.0,
        source: str = "already-rectified pair",
    ) -> Calibration:
        """The calibration of an already-rectified, distortion-free pair: focal lengths
        ``fx, fy`` (px), baseline (m, left camera on the left), the left principal point and
        ``doffs`` (right minus left principal point x, px) of images of ``image_size``."""
        width, height = image_size
        problems = [
            f"focal length {name} = {value:g} px must be positive"
            for name, value in (("fx", fx), ("fy", fy))
            if not value > 0
        ]
        if not baseline_m > 0:
            problems.append(f"baseline {baseline_m * 1e3:g} mm must be positive")
        if not (0 <= cx < width and 0 <= cy < height):
            problems.append(
                f"principal point ({cx:g}, {cy:g}) lies outside the {width}x{height} image"
            )
        if not (np.isfinite(doffs) and 0 <= cx + doffs < width):
            problems.append(
                f"doffs {doffs:g} px puts the right principal point ({cx + doffs:g}) "
                f"outside the {width}-px wide image"
            )
        if problems:
            raise CalibrationError("; ".join(problems))
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        K2 = K.copy()
        K2[0, 2] = cx + doffs
        P1, P2 = np.hstack([K, np.zeros((3, 1))]), np.hstack([K2, np.zeros((3, 1))])
        P2[0, 3] = -fx * baseline_m
        return cls(
            K1=K,
            D1=np.zeros(5),
            K2=K2,
            D2=np.zeros(5),
            R=np.eye(3),
            T=np.array([-baseline_m, 0.0, 0.0]),
            R1=np.eye(3),
            R2=np.eye(3),
            P1=P1,
            P2=P2,
            Q=reprojection_matrix(P1, P2),
            image_size=(width, height),
            info={"source": source},
        )

    @property
    def cx(self) -> float:
        """Principal point x of the rectified left image (pixels)."""
        return float(self.P1[0, 2])

    @property
    def cy(self) -> float:
        """Principal point y of the rectified left image (pixels)."""
        return float(self.P1[1, 2])

    @property
    def has_projector(self) -> bool:
        """Whether projector intrinsics and pose are present."""
        return self.K_proj is not None

    def rectification_maps(
        self,
    ) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
        """``((map1x, map1y), (map2x, map2y))`` for ``cv2.remap`` of left and right images."""
        left = cv2.initUndistortRectifyMap(
            self.K1, self.D1, self.R1, self.P1, self.image_size, cv2.CV_32FC1
        )
        right = cv2.initUndistortRectifyMap(
            self.K2, self.D2, self.R2, self.P2, self.image_size, cv2.CV_32FC1
        )
        return left, right

    def scaled(self, scale: float, scale_y: float | None = None) -> Calibration:
        """The calibration of the same cameras with images resized by ``scale`` (e.g. 0.5 for
        half resolution), rows by ``scale_y`` when given (anisotropic pixels); pixel centres
        stay at integer coordinates, as in OpenCV."""
        sy = scale if scale_y is None else scale_y
        size = (round(self.image_size[0] * scale), round(self.image_size[1] * sy))
        S = np.array([[scale, 0.0, (scale - 1) / 2], [0.0, sy, (sy - 1) / 2], [0, 0, 1]])
        P1, P2 = S @ self.P1, S @ self.P2
        return self.replace(
            K1=S @ self.K1,
            K2=S @ self.K2,
            P1=P1,
            P2=P2,
            Q=reprojection_matrix(P1, P2),
            image_size=size,
            per_view_rms_px=None,
        )

    def rectify(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rectify a pair: rows of the two images become epipolar lines.

        :param left: the left image as captured (``image_size``).
        :param right: the right image as captured.
        :returns: the rectified left and right images.
        :raises CalibrationError: an image is not of the calibration's size.
        """
        for name, img in (("left", left), ("right", right)):
            size = (img.shape[1], img.shape[0])
            mismatch = size_mismatch(
                f"the {name} image has", size, "the calibration", self.image_size
            )
            if mismatch:
                raise CalibrationError(mismatch)
        (l1, l2), (r1, r2) = self.rectification_maps()
        return (
            cv2.remap(left, l1, l2, cv2.INTER_LINEAR),
            cv2.remap(right, r1, r2, cv2.INTER_LINEAR),
        )

    def rectify_points(
        self, left_px: np.ndarray, right_px: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Raw left and right pixel positions (n×2 each) mapped into the rectified images."""

        def one(
            points: np.ndarray, K: np.ndarray, D: np.ndarray, R: np.ndarray, P: np.ndarray
        ) -> np.ndarray:
            points = np.asarray(points, np.float64).reshape(-1, 1, 2)
            return cv2.undistortPoints(points, K, D, R=R, P=P).reshape(-1, 2)

        return (
            one(left_px, self.K1, self.D1, self.R1, self.P1),
            one(right_px, self.K2, self.D2, self.R2, self.P2),
        )

    # --- file format --------------------------------------------------------------------
    def to_yaml_text(self) -> str:
        """The calibration as OpenCV FileStorage YAML text."""
        fs = cv2.FileStorage(
            "", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY | cv2.FILE_STORAGE_FORMAT_YAML
        )
        fs.write("format", "vbfe-calibration")
        fs.write("format_version", FORMAT_VERSION)
        fs.write("image_width", self.image_size[0])
        fs.write("image_height", self.image_size[1])
        for name in (*_MATRICES, *_OPTIONAL_MATRICES):
            value = getattr(self, name)
            if value is not None:
                fs.write(name, value.reshape(-1, 1) if name in _VECTORS else value)
        for name in ("f", "B", "cx", "cy"):
            fs.write(name, getattr(self, name))
        for name in ("rms_left_px", "rms_right_px", "rms_stereo_px", "rms_projector_px"):
            value = getattr(self, name)
            if np.isfinite(value):
                fs.write(name, float(value))
        if self.projector_size is not None:
            fs.write("projector_width", self.projector_size[0])
            fs.write("projector_height", self.projector_size[1])
        _write_info(fs, _INFO_NODE, json.loads(json.dumps(self.info, sort_keys=True)))
        return fs.releaseAndGetString()

    @classmethod
    def from_yaml_text(cls, text: str, source: str = "<text>") -> Calibration:
        """Parse calibration YAML text.

        :param text: OpenCV FileStorage YAML, as :meth:`to_yaml_text` writes it.
        :param source: names the text in error messages (e.g. its file).
        :raises CalibrationError: the text is not such YAML, lacks a matrix, or holds one of the
            wrong shape or an impossible value.
        """
        try:
            fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
        except (cv2.error, SystemError) as exc:  # SystemError: OpenCV's parser error, wrapped
            cause = exc.__cause__ or exc
            raise CalibrationError(
                f"{source} is not OpenCV FileStorage YAML ({str(cause).strip().splitlines()[-1]})"
            ) from None
        try:
            return cls._from_storage(fs, source)
        except cv2.error as exc:  # a node of the wrong kind (e.g. a list where a map is needed)
            raise CalibrationError(
                f"{source} is not a vbfe calibration file ({exc.err.strip() or 'unreadable node'})"
            ) from None
        finally:
            fs.release()

    @classmethod
    def _from_storage(cls, fs: cv2.FileStorage, source: str) -> Calibration:
        if not fs.root().isMap():
            raise CalibrationError(
                f"{source} is not a vbfe calibration file (its top level is "
                "not a map of named nodes)"
            )

        def node(name: str) -> cv2.FileNode | None:
            n = fs.getNode(name)
            return None if n.empty() or n.isNone() else n

        def number(name: str) -> float | None:
            n = node(name)
            if n is None:
                return None
            if not (n.isInt() or n.isReal()):
                raise CalibrationError(f"{source}: {name} is not a number")
            return n.real()

        fmt = node("format")
        if fmt is None or not fmt.isString() or fmt.string() != "vbfe-calibration":
            raise CalibrationError(
                f"{source} is not a vbfe calibration file (no 'format: "
                "vbfe-calibration'); write one with 'vbfe calibrate stereo'"
            )
        kwargs: dict[str, Any] = {}
        for name in (*_MATRICES, *_OPTIONAL_MATRICES):
            n = node(name)
            if n is None:
                if name in _MATRICES:
                    raise CalibrationError(
                        f"{source} has no {name}; the file is incomplete, "
                        "recalibrate with 'vbfe calibrate stereo'"
                    )
                continue
            mat = n.mat() if n.isMap() else None
            if mat is None:
                raise CalibrationError(f"{source}: {name} is not a matrix (!!opencv-matrix)")
            kwargs[name] = mat
        width, height = (number(name) for name in ("image_width", "image_height"))
        if width is None or height is None:
            raise CalibrationError(f"{source} has no image_width and image_height")
        kwargs["image_size"] = (int(width), int(height))
        for name in ("rms_left_px", "rms_right_px", "rms_stereo_px", "rms_projector_px"):
            if node(name) is not None:
                kwargs[name] = number(name)
        if node("projector_width") is not None:
            kwargs["projector_size"] = (
                int(number("projector_width") or 0),
                int(number("projector_height") or 0),
            )
        info = node(_INFO_NODE)
        if info is not None:
            if not info.isMap():
                raise CalibrationError(f"{source}: {_INFO_NODE} is not a map of named nodes")
            kwargs["info"] = _read_info(info)
        else:
            kwargs["info"] = _read_old_info(
                node(_OLD_INFO_NODES[0]), node(_OLD_INFO_NODES[1]), source
            )
        try:
            return cls(**kwargs)
        except CalibrationError as exc:
            raise CalibrationError(f"{source}: {exc}") from None

    def save(self, path: str | Path) -> Path:
        """Write the YAML file atomically (a crash leaves the old file intact), after reading
        the text back: a calibration that would not load again is never written.

        :param path: the file to write (replaced if it exists: callers check outputs first).
        :returns: ``path``.
        :raises CalibrationError: the text does not read back as written.
        :raises OSError: the file cannot be written.
        """
        path = Path(path)
        text = self.to_yaml_text()
        back = Calibration.from_yaml_text(text, source=f"calibration written to {path}")
        if back.info != json.loads(json.dumps(self.info)) or not all(
            np.allclose(getattr(back, name), getattr(self, name), rtol=1e-12, atol=0)
            for name in _MATRICES
        ):
            raise CalibrationError(
                f"the calibration for {path} does not read back as written; "
                "nothing was written (please report this)"
            )
        return write_bytes_atomic(path, text)

    @classmethod
    def load(cls, path: str | Path) -> Calibration:
        """Read a calibration YAML file.

        :param path: the file, as :meth:`save` wrote it.
        :raises CalibrationError: the file is missing, not text, or not a valid calibration.
        """
        path = Path(path)
        try:
            text = path.read_text(encoding="utf-8")
        except FileNotFoundError:
            raise CalibrationError(
                f"calibration file {path} does not exist; create one with 'vbfe calibrate stereo'"
            ) from None
        except UnicodeDecodeError:
            raise CalibrationError(f"{path} is not a text (YAML) calibration file") from None
        return cls.from_yaml_text(text, source=str(path))

    def replace(self, **changes: Any) -> Calibration:
        """A copy with some fields changed."""
        return dataclasses.replace(self, **changes)


def _plain(text: str) -> bool:
    """Whether FileStorage writes and reads ``text`` back unchanged as a YAML scalar."""
    quoted = len(text) >= 2 and text[0] == text[-1] and text[0] in "'\""
    return not quoted and text == text.strip() and text.lower() not in _PLAIN_WORDS


def _write_info(fs: cv2.FileStorage, name: str, value: Any) -> None:
    """``value`` (JSON-like) as plain YAML nodes: maps, sequences (numbers inline), numbers
    and strings. Rare cases get a one-key map: ``{null: 1}`` for None, ``{base64: …}`` for a
    string FileStorage would change (quoted, padded, a YAML word), and a dict whose keys are
    not FileStorage keys (e.g. ``"05"``) is a sequence of ``{key, value}`` maps."""
    if isinstance(value, dict):
        if all(isinstance(k, str) and _KEY.fullmatch(k) for k in value):
            fs.startWriteStruct(name, cv2.FileNode_MAP)
            for key, item in value.items():
                _write_info(fs, key, item)
        else:
            fs.startWriteStruct(name, cv2.FileNode_SEQ)
            for key, item in value.items():
                _write_info(fs, "", {"key": key, "value": item})
        fs.endWriteStruct()
    elif isinstance(value, list):
        numbers = all(isinstance(v, (int, float)) for v in value)
        fs.startWriteStruct(name, cv2.FileNode_SEQ | (cv2.FileNode_FLOW if numbers else 0))
        for item in value:
            _write_info(fs, "", item)
        fs.endWriteStruct()
    elif value is None:
        _write_info(fs, name, {"null": 1})
    elif isinstance(value, (bool, int)):
        fs.write(name, int(value))
    elif isinstance(value, float):
        fs.write(name, value)
    elif _plain(value):
        fs.write(name, value)
    else:
        _write_info(fs, name, {"base64": base64.b64encode(value.encode()).decode("ascii")})


def _read_info(node: cv2.FileNode) -> Any:
    """The value :func:`_write_info` wrote."""
    if node.isMap():
        keys = list(node.keys())
        if keys == ["null"]:
            return None
        if keys == ["base64"]:
            return base64.b64decode(node.getNode("base64").string()).decode("utf-8")
        return {key: _read_info(node.getNode(key)) for key in keys}
    if node.isSeq():
        items = [node.at(i) for i in range(node.size())]
        if items and all(item.isMap() and list(item.keys()) == ["key", "value"] for item in items):
            return {
                item.getNode("key").string(): _read_info(item.getNode("value")) for item in items
            }
        return [_read_info(item) for item in items]
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return node.real()
    return node.string()


def _read_old_info(
    node: cv2.FileNode | None, old: cv2.FileNode | None, source: str
) -> dict[str, Any]:
    """The info dict of files written before the YAML map: base64 pieces, or raw JSON pieces
    in still older files."""
    chosen = node if node is not None else old
    if chosen is None:
        return {}
    items = [chosen.at(i) for i in range(chosen.size())] if chosen.isSeq() else [chosen]
    if not all(item.isString() for item in items):
        name = _OLD_INFO_NODES[0] if node is not None else _OLD_INFO_NODES[1]
        raise CalibrationError(f"{source}: {name} is not a sequence of strings")
    text = "".join(item.string() for item in items)
    try:
        if node is not None:
            text = base64.b64decode(text, validate=True).decode("utf-8")
        info = json.loads(text)
    except (binascii.Error, UnicodeDecodeError, json.JSONDecodeError):
        raise CalibrationError(f"{source}: the info text does not decode (damaged file)") from None
    if not isinstance(info, dict):
        raise CalibrationError(f"{source}: the info text is not a JSON object")
    return info


def _shape_ok(shape: tuple[int, ...], expected: tuple[int, ...]) -> bool:
    return len(shape) == len(expected) and all(
        e in (-1, s) for s, e in zip(shape, expected, strict=False)
    )


def load_calibration(path: str | Path) -> Calibration:
    """A calibration from a YAML file or from a recorded session (``.h5``) that stores one."""
    path = Path(path)
    if path.suffix.lower() in (".h5", ".hdf5"):
        from vbfe.acquire import SessionReader

        with SessionReader(path) as reader:
            return stored_calibration(reader.calibration_yaml(), path)
    return Calibration.load(path)


def stored_calibration(yaml_text: str | None, session_path: str | Path) -> Calibration:
    """The calibration a session stores (its calibration YAML text), refused when none."""
    if yaml_text is None:
        raise CalibrationError(
            f"session {session_path} holds no calibration; store one with "
            "'vbfe calibrate stereo ... --store-in SESSION' or pass a "
            "calibration YAML file (--calib FILE.yaml)"
        )
    return Calibration.from_yaml_text(yaml_text, source=f"calibration in {session_path}")
