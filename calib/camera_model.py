"""A single camera's intrinsics and their file (OpenCV FileStorage YAML, ``format:
vbfe-camera``, see docs/reference/calibration-format.md): what ``vbfe calibrate camera`` writes and
``vbfe calibrate stereo --intrinsics`` reads as fixed intrinsics."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from vbfe.common.errors import CalibrationError
from vbfe.common.files import write_bytes_atomic

CAMERA_FORMAT = "vbfe-camera"


@dataclass
class CameraModel:
    """Pinhole intrinsics ``K``, distortion ``D`` (OpenCV order), image size (w, h), overall and
    per-view RMS (px), standard deviations of fx, fy, cx, cy, k1, k2, p1, p2, k3, the views
    used and the views dropped (``name: reason``)."""

    K: np.ndarray
    D: np.ndarray
    image_size: tuple[int, int]
    rms_px: float = float("nan")
    per_view_rms_px: np.ndarray = field(default_factory=lambda: np.zeros(0))
    std_intrinsics: np.ndarray = field(default_factory=lambda: np.zeros(9))
    views: list[str] = field(default_factory=list)
    dropped: list[str] = field(default_factory=list)
    board: str = ""

    def __post_init__(self) -> None:
        self.K = np.asarray(self.K, np.float64)
        self.D = np.asarray(self.D, np.float64).reshape(-1)
        self.per_view_rms_px = np.asarray(self.per_view_rms_px, np.float64).reshape(-1)
        self.std_intrinsics = np.asarray(self.std_intrinsics, np.float64).reshape(-1)
        self.image_size = (int(self.image_size[0]), int(self.image_size[1]))
        if self.K.shape != (3, 3) or self.D.size not in (4, 5, 8, 12, 14):
            raise CalibrationError(
                f"camera model has K of shape {self.K.shape} and "
                f"{self.D.size} distortion coefficients; expected 3x3 and "
                "4, 5, 8, 12 or 14"
            )

    def save(self, path: str | Path) -> Path:
        """Write the YAML file atomically."""
        fs = cv2.FileStorage(
            "", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY | cv2.FILE_STORAGE_FORMAT_YAML
        )
        fs.write("format", CAMERA_FORMAT)
        fs.write("format_version", 1)
        fs.write("image_width", self.image_size[0])
        fs.write("image_height", self.image_size[1])
        fs.write("K", self.K)
        fs.write("D", self.D.reshape(-1, 1))
        fs.write("rms_px", float(self.rms_px))
        fs.write("std_intrinsics", self.std_intrinsics.reshape(-1, 1))
        if self.per_view_rms_px.size:
            fs.write("per_view_rms_px", self.per_view_rms_px.reshape(-1, 1))
        fs.write("board", self.board)
        for key, items in (("views", self.views), ("dropped_views", self.dropped)):
            fs.startWriteStruct(key, cv2.FileNode_SEQ)
            for item in items:
                fs.write("", item)
            fs.endWriteStruct()
        return write_bytes_atomic(path, fs.releaseAndGetString())

    @classmethod
    def load(cls, path: str | Path) -> CameraModel:
        """Read a camera YAML file written by :meth:`save`."""
        path = Path(path)
        if not path.is_file():
            raise CalibrationError(
                f"camera file {path} does not exist; write one with "
                "'vbfe calibrate camera VIEWS -o cam.yaml'"
            )
        try:
            fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
        except (cv2.error, SystemError):
            raise CalibrationError(f"{path} is not OpenCV FileStorage YAML") from None
        try:
            if fs.getNode("format").string() != CAMERA_FORMAT:
                raise CalibrationError(
                    f"{path} is not a vbfe camera file (no 'format: "
                    f"{CAMERA_FORMAT}'); write one with 'vbfe calibrate "
                    "camera'"
                )
            mats = {}
            for key in ("K", "D", "std_intrinsics", "per_view_rms_px"):
                node = fs.getNode(key)
                mats[key] = None if node.empty() else node.mat()
            if mats["K"] is None or mats["D"] is None:
                raise CalibrationError(
                    f"{path} has no K or D; recalibrate with 'vbfe calibrate camera'"
                )

            def strings(key: str) -> list[str]:
                node = fs.getNode(key)
                return [node.at(i).string() for i in range(node.size())] if node.isSeq() else []

            return cls(
                K=mats["K"],
                D=mats["D"],
                image_size=(
                    int(fs.getNode("image_width").real()),
                    int(fs.getNode("image_height").real()),
                ),
                rms_px=fs.getNode("rms_px").real(),
                per_view_rms_px=(
                    mats["per_view_rms_px"] if mats["per_view_rms_px"] is not None else np.zeros(0)
                ),
                std_intrinsics=(
                    mats["std_intrinsics"] if mats["std_intrinsics"] is not None else np.zeros(9)
                ),
                views=strings("views"),
                dropped=strings("dropped_views"),
                board=fs.getNode("board").string(),
            )
        except CalibrationError as exc:
            raise CalibrationError(
                f"{path}: {exc}" if str(path) not in str(exc) else str(exc)
            ) from None
        finally:
            fs.release()
