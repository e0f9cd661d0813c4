"""Calibrations made by other tools, read into vbfe's :class:`Calibration` (the inverse of
:mod:`vbfe.calib.export`): OpenCV's stereo sample files (``M1 D1 M2 D2 R T``, also ``K1 …``,
YAML or XML, one file or intrinsics + extrinsics), a Kalibr camchain, a ROS ``camera_info``
pair (left, right) and a Middlebury ``calib.txt``. See docs/reference/calibration-format.md."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, TypeVar

import cv2
import numpy as np

from vbfe.calib.calibration import Calibration, reprojection_matrix
from vbfe.calib.rectify import stereo_rectify
from vbfe.common.errors import CalibrationError

IMPORT_FORMATS = ("opencv", "kalibr", "ros", "middlebury")

V = TypeVar("V")


def _read(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise CalibrationError(f"{path} does not exist") from None
    except (UnicodeDecodeError, IsADirectoryError):
        raise CalibrationError(f"{path} is not a text calibration file") from None


def _indent_block_sequences(text: str) -> str:
    """PyYAML's ``key:\\n- item`` (a sequence at its key's indentation, as Kalibr and ROS
    write) indented under its key, the form OpenCV's YAML reader takes."""
    out, key_indent = [], None
    for line in text.splitlines():
        stripped = line.lstrip(" ")
        indent = len(line) - len(stripped)
        if stripped.startswith("- ") and key_indent is not None and indent == key_indent:
            line = "  " + line
        elif stripped and not stripped.startswith("#"):
            key_indent = indent if re.match(r"^[^\s:]+:\s*$", stripped) else None
        out.append(line)
    return "\n".join(out) + "\n"


class _Storage:
    """Nodes of one or more OpenCV FileStorage texts (YAML or XML)."""

    def __init__(self, texts: list[tuple[str, str]]) -> None:
        self._files = []
        for source, text in texts:
            try:
                fs = cv2.FileStorage(
                    _indent_block_sequences(text) if not text.lstrip().startswith("<") else text,
                    cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY,
                )
            except (cv2.error, SystemError):
                raise CalibrationError(
                    f"{source} is not YAML or XML that OpenCV can read"
                ) from None
            self._files.append((source, fs))

    def node(self, *path: str) -> cv2.FileNode | None:
        for _, fs in self._files:
            node = fs.getNode(path[0])
            for name in path[1:]:
                node = node.getNode(name) if node.isMap() else cv2.FileNode()
            if not node.empty() and not node.isNone():
                return node
        return None

    def has(self, name: str) -> bool:
        return self.node(name) is not None

    def matrix(self, *names: str) -> np.ndarray | None:
        """The first of ``names`` present, as a matrix (``!!opencv-matrix``, a ROS
        ``{rows, cols, data}`` map or a list of numbers / rows)."""
        for name in names:
            node = self.node(*name.split("/"))
            if node is None:
                continue
            if node.isMap() and not node.getNode("dt").empty():  # !!opencv-matrix
                return np.asarray(node.mat(), np.float64)
            if node.isMap() and node.getNode("data").isSeq():
                rows, cols = int(node.getNode("rows").real()), int(node.getNode("cols").real())
                return np.asarray(_numbers(node.getNode("data")), np.float64).reshape(rows, cols)
            if node.isSeq():
                return np.asarray(_numbers(node), np.float64)
        return None

    def number(self, name: str) -> float | None:
        node = self.node(*name.split("/"))
        return None if node is None or not (node.isInt() or node.isReal()) else node.real()

    def text(self, name: str) -> str | None:
        node = self.node(*name.split("/"))
        return node.string() if node is not None and node.isString() else None


def _numbers(node: cv2.FileNode) -> list:
    items = [node.at(i) for i in range(node.size())]
    return [_numbers(item) if item.isSeq() else item.real() for item in items]


def _need(value: V | None, what: str, source: str) -> V:
    if value is None:
        raise CalibrationError(f"{source} has no {what}")
    return value


def _stereo(
    K1: np.ndarray,
    D1: np.ndarray,
    K2: np.ndarray,
    D2: np.ndarray,
    R: np.ndarray,
    T: np.ndarray,
    size: tuple[int, int],
    source: str,
    rectified: dict[str, Any] | None = None,
) -> Calibration:
    """The calibration of a pair imported from ``source``, with its rectification as given or
    (``rectified`` None) as ``stereoRectify`` finds it (zero disparity, alpha 0)."""
    if rectified is None:
        rect = stereo_rectify(K1, D1, K2, D2, size, R, T, alpha=0, zero_disparity=True)
        rectified = {"R1": rect.R1, "R2": rect.R2, "P1": rect.P1, "P2": rect.P2, "Q": rect.Q}
    return Calibration(
        K1=K1, D1=D1, K2=K2, D2=D2, R=R, T=T, image_size=size, **rectified, info={"source": source}
    )


def _opencv(
    store: _Storage, source: str, size: tuple[int, int] | None, unit_m: float
) -> Calibration:
    K1 = _need(store.matrix("M1", "K1"), "M1 (or K1), the left camera matrix", source)
    K2 = _need(store.matrix("M2", "K2"), "M2 (or K2), the right camera matrix", source)
    D1 = _need(store.matrix("D1"), "D1, the left distortion", source).reshape(-1)
    D2 = _need(store.matrix("D2"), "D2, the right distortion", source).reshape(-1)
    R = _need(store.matrix("R"), "R, the left-to-right rotation", source)
    T = _need(store.matrix("T"), "T, the left-to-right translation", source).reshape(3) * unit_m
    width, height = store.number("image_width"), store.number("image_height")
    if width and height:
        size = (int(width), int(height))
    if size is None:
        raise CalibrationError(
            f"{source} does not say the image size (OpenCV's stereo sample "
            "files do not); give it with --image-size WIDTHxHEIGHT"
        )
    names = ("R1", "R2", "P1", "P2", "Q")
    given: dict[str, Any] = {name: store.matrix(name) for name in names}
    usable = all(v is not None for v in given.values()) and unit_m == 1.0
    return _stereo(
        K1, D1, K2, D2, R, T, size, f"OpenCV stereo files ({source})", given if usable else None
    )


def _kalibr(store: _Storage, source: str) -> Calibration:
    cams = []
    for cam in ("cam0", "cam1"):
        model = store.text(f"{cam}/camera_model")
        dist = store.text(f"{cam}/distortion_model")
        if model != "pinhole" or dist not in ("radtan", "none"):
            raise CalibrationError(
                f"{source}: {cam} is {model}-{dist}; vbfe reads "
                "pinhole-radtan (OpenCV's k1, k2, p1, p2) cameras only"
            )
        fu, fv, pu, pv = _need(store.matrix(f"{cam}/intrinsics"), f"{cam} intrinsics", source)
        coeffs = store.matrix(f"{cam}/distortion_coeffs")
        D = np.zeros(5)
        if coeffs is not None and dist == "radtan":
            D[:4] = coeffs.reshape(-1)[:4]
        width, height = _need(store.matrix(f"{cam}/resolution"), f"{cam} resolution", source)
        cams.append(
            (np.array([[fu, 0, pu], [0, fv, pv], [0, 0, 1.0]]), D, (int(width), int(height)))
        )
    if cams[0][2] != cams[1][2]:
        raise CalibrationError(
            f"{source}: cam0 is {cams[0][2]} and cam1 {cams[1][2]} px; vbfe "
            "needs both eyes at one resolution"
        )
    T_cn = _need(store.matrix("cam1/T_cn_cnm1"), "cam1 T_cn_cnm1 (cam0 to cam1)", source)
    T_cn = T_cn.reshape(4, 4)
    (K1, D1, size), (K2, D2, _) = cams
    R, T = T_cn[:3, :3], T_cn[:3, 3]
    return _stereo(K1, D1, K2, D2, R, T, size, f"Kalibr camchain ({source})")


def _ros(stores: list[_Storage], sources: list[str]) -> Calibration:
    eyes: list[dict[str, Any]] = []
    for store, source in zip(stores, sources, strict=False):
        width, height = store.number("image_width"), store.number("image_height")
        eyes.append(
            dict(
                K=_need(store.matrix("camera_matrix"), "camera_matrix", source).reshape(3, 3),
                D=_need(
                    store.matrix("distortion_coefficients"), "distortion_coefficients", source
                ).reshape(-1),
                R=_need(
                    store.matrix("rectification_matrix"), "rectification_matrix", source
                ).reshape(3, 3),
                P=_need(store.matrix("projection_matrix"), "projection_matrix", source).reshape(
                    3, 4
                ),
                size=(
                    int(_need(width, "image_width", source)),
                    int(_need(height, "image_height", source)),
                ),
            )
        )
    left, right = eyes
    if left["size"] != right["size"]:
        raise CalibrationError(
            f"{sources[0]} is for {left['size']} and {sources[1]} for "
            f"{right['size']} px images; give the left and right files of "
            "one camera mode"
        )
    if not right["P"][0, 3] < 0 <= left["P"][0, 3] + 1e-12:
        raise CalibrationError(
            f"{sources[1]} is not the right eye of {sources[0]} (its "
            "projection_matrix has no negative Tx = -fx·B); give the left "
            "file first"
        )
    # rectified right = rectified left + (Tx, 0, 0): X_r = R2ᵀ (R1 X_l + t)
    t = np.array([right["P"][0, 3] / right["P"][0, 0], 0.0, 0.0])
    R = right["R"].T @ left["R"]
    T = right["R"].T @ t
    return Calibration(
        K1=left["K"],
        D1=left["D"],
        K2=right["K"],
        D2=right["D"],
        R=R,
        T=T,
        R1=left["R"],
        R2=right["R"],
        P1=left["P"],
        P2=right["P"],
        Q=reprojection_matrix(left["P"], right["P"]),
        image_size=left["size"],
        info={"source": f"ROS camera_info pair ({', '.join(sources)})"},
    )


def _middlebury(text: str, source: str) -> Calibration:
    values = dict(re.findall(r"^\s*(\w+)\s*=\s*(.+?)\s*$", text, re.M))

    def camera(name: str) -> np.ndarray:
        if name not in values:
            raise CalibrationError(f"{source} has no {name}=[...] line")
        rows = [row.split() for row in values[name].strip("[]").split(";")]
        try:
            K = np.array(rows, np.float64)
        except ValueError:
            raise CalibrationError(f"{source}: {name} is not a 3x3 matrix") from None
        if K.shape != (3, 3):
            raise CalibrationError(f"{source}: {name} is {K.shape}, not 3x3")
        return K

    def number(name: str) -> float:
        try:
            return float(values[name])
        except (KeyError, ValueError):
            raise CalibrationError(f"{source} has no number {name}=...") from None

    K0, K1 = camera("cam0"), camera("cam1")
    doffs = number("doffs")
    if abs(K1[0, 2] - K0[0, 2] - doffs) > 1e-3:
        raise CalibrationError(
            f"{source}: doffs {doffs:g} is not cam1's cx minus cam0's "
            f"({K1[0, 2] - K0[0, 2]:g}); the file is inconsistent"
        )
    return Calibration.rectified(
        K0[0, 0],
        K0[1, 1],
        number("baseline") * 1e-3,
        K0[0, 2],
        K0[1, 2],
        (int(number("width")), int(number("height"))),
        doffs,
        source=f"Middlebury calib.txt ({source})",
    )


def detect_format(texts: list[str]) -> str:
    """Which of :data:`IMPORT_FORMATS` the file texts are."""
    first = texts[0]
    if re.search(r"^\s*cam0\s*=\s*\[", first, re.M):
        return "middlebury"
    if re.search(r"^cam0:\s*$", first, re.M) and "intrinsics" in first:
        return "kalibr"
    if "camera_matrix" in first and "projection_matrix" in first:
        return "ros"
    if re.search(r"\b(M1|K1)\b", "\n".join(texts)):
        return "opencv"
    raise CalibrationError(
        "not a calibration vbfe can import: expected OpenCV stereo files "
        "(M1 D1 M2 D2 R T), a Kalibr camchain, a ROS camera_info pair or a "
        "Middlebury calib.txt"
    )


def import_calibration(
    paths: list[str | Path], image_size: tuple[int, int] | None = None, unit_m: float = 1.0
) -> tuple[Calibration, str]:
    """The calibration in another tool's files, and their format. ``image_size`` is needed for
    OpenCV's stereo sample files, which do not hold it; ``unit_m`` is the length of their T's
    unit (1: metres; OpenCV's sample measures in board squares)."""
    texts = [_read(Path(p)) for p in paths]
    fmt = detect_format(texts)
    wanted = {"ros": 2, "middlebury": 1, "kalibr": 1}.get(fmt)
    if wanted is not None and len(paths) != wanted:
        raise CalibrationError(
            f"a {fmt} calibration is {wanted} file"
            f"{'s (left, right)' if wanted == 2 else ''}; got {len(paths)}"
        )
    if len(paths) > 2:
        raise CalibrationError(f"give at most two files (got {len(paths)})")
    sources = [str(p) for p in paths]
    if fmt == "middlebury":
        return _middlebury(texts[0], sources[0]), fmt
    stores = [_Storage([(s, t)]) for s, t in zip(sources, texts, strict=False)]
    if fmt == "ros":
        return _ros(stores, sources), fmt
    if fmt == "kalibr":
        return _kalibr(stores[0], sources[0]), fmt
    return _opencv(
        _Storage(list(zip(sources, texts, strict=False))), " + ".join(sources), image_size, unit_m
    ), fmt
