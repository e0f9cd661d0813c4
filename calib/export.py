"""Export a calibration to the formats other tools read: ROS ``camera_info`` YAML (one file per
eye), a Kalibr camchain YAML, OpenCV's stereo sample files (``intrinsics.yml`` +
``extrinsics.yml``) and a Middlebury ``calib.txt`` (the rectified pair). See
docs/reference/calibration-format.md; :mod:`vbfe.calib.importers` reads them back."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from vbfe.calib.calibration import Calibration
from vbfe.common.errors import CalibrationError
from vbfe.common.files import write_bytes_atomic

FORMATS = ("ros", "kalibr", "opencv", "middlebury")


def _yaml_float(value: float) -> str:
    """Shortest round-trip text of ``value`` that YAML 1.1 parsers (PyYAML) read as a float:
    a mantissa with a dot (``1.0e-05``, not ``1e-05``) and ``.nan`` / ``.inf``."""
    if not np.isfinite(value):
        return ".nan" if np.isnan(value) else ("-.inf" if value < 0 else ".inf")
    text = repr(float(value))
    mantissa, _, exponent = text.partition("e")
    if "." not in mantissa:
        mantissa += ".0"
    return mantissa + ("e" + exponent if exponent else "")


def _numbers(values: np.ndarray) -> str:
    return "[" + ", ".join(_yaml_float(v) for v in np.asarray(values, np.float64).ravel()) + "]"


def _matrix(name: str, M: np.ndarray) -> str:
    M = np.atleast_2d(np.asarray(M, np.float64))
    return f"{name}:\n  rows: {M.shape[0]}\n  cols: {M.shape[1]}\n  data: {_numbers(M)}\n"


def ros_distortion_model(D: np.ndarray) -> str:
    """ROS camera_info distortion model of OpenCV coefficients D."""
    if D.size == 5:
        return "plumb_bob"
    if D.size == 8:
        return "rational_polynomial"
    raise CalibrationError(
        f"{D.size} distortion coefficients have no ROS camera_info model "
        "(plumb_bob needs 5, rational_polynomial 8)"
    )


def ros_camera_info(
    name: str, size: tuple[int, int], K: np.ndarray, D: np.ndarray, R: np.ndarray, P: np.ndarray
) -> str:
    """One eye's ``camera_info`` YAML text (camera_calibration_parsers layout)."""
    return (
        f"image_width: {size[0]}\nimage_height: {size[1]}\ncamera_name: {name}\n"
        + _matrix("camera_matrix", K)
        + f"distortion_model: {ros_distortion_model(D)}\n"
        + _matrix("distortion_coefficients", D.reshape(1, -1))
        + _matrix("rectification_matrix", R)
        + _matrix("projection_matrix", P)
    )


def kalibr_camchain(
    cal: Calibration, topics: tuple[str, str] = ("/cam0/image_raw", "/cam1/image_raw")
) -> str:
    """Kalibr camchain YAML text: pinhole-radtan cam0 (left) and cam1 (right) with
    ``T_cn_cnm1`` = left → right (OpenCV's ``R, T``)."""
    out = []
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = cal.R, cal.T
    for cam, K, D, topic in (
        ("cam0", cal.K1, cal.D1, topics[0]),
        ("cam1", cal.K2, cal.D2, topics[1]),
    ):
        if D.size > 4 and np.any(D[4:] != 0):
            raise CalibrationError(
                f"{cam} has k3 = {D[4]:.4g} (or higher terms) but Kalibr's "
                "radtan model holds only k1, k2, p1, p2; recalibrate with "
                "--fix-k3 or use --format ros/opencv"
            )
        out.append(
            f"{cam}:\n  camera_model: pinhole\n"
            f"  intrinsics: {_numbers(K[[0, 1, 0, 1], [0, 1, 2, 2]])}\n"
            f"  distortion_model: radtan\n  distortion_coeffs: {_numbers(D[:4])}\n"
            f"  resolution: [{cal.image_size[0]}, {cal.image_size[1]}]\n"
            f"  rostopic: {topic}\n"
        )
        if cam == "cam1":
            out.append("  T_cn_cnm1:\n" + "".join(f"  - {_numbers(row)}\n" for row in T))
    return "".join(out)


def middlebury_calib(cal: Calibration) -> str:
    """Middlebury ``calib.txt`` text of the rectified pair: ``cam0``/``cam1`` (the rectified
    camera matrices), ``doffs`` (px), ``baseline`` (mm), ``width``, ``height``."""

    def camera(P: np.ndarray) -> str:
        return "[" + "; ".join(" ".join(repr(float(v)) for v in row) for row in P[:, :3]) + "]"

    return (
        f"cam0={camera(cal.P1)}\ncam1={camera(cal.P2)}\ndoffs={cal.doffs!r}\n"
        f"baseline={cal.B * 1e3!r}\nwidth={cal.image_size[0]}\n"
        f"height={cal.image_size[1]}\n"
    )


def _opencv_files(cal: Calibration) -> tuple[str, str]:
    texts = []
    for names in (("M1", "D1", "M2", "D2"), ("R", "T", "R1", "R2", "P1", "P2", "Q")):
        fs = cv2.FileStorage(
            "", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY | cv2.FILE_STORAGE_FORMAT_YAML
        )
        if "M1" in names:  # OpenCV's sample leaves the size out; its readers skip these nodes
            fs.write("image_width", cal.image_size[0])
            fs.write("image_height", cal.image_size[1])
        for name in names:
            value = getattr(cal, {"M1": "K1", "M2": "K2"}.get(name, name))
            fs.write(name, value.reshape(-1, 1) if value.ndim == 1 else value)
        texts.append(fs.releaseAndGetString())
    return texts[0], texts[1]


def export_paths(fmt: str, out_dir: str | Path, stem: str = "calibration") -> list[Path]:
    """The files :func:`export_calibration` writes: ros: ``<stem>_left.yaml``,
    ``<stem>_right.yaml``; kalibr: ``<stem>-camchain.yaml``; opencv: ``intrinsics.yml``,
    ``extrinsics.yml``; middlebury: ``calib.txt``."""
    if fmt not in FORMATS:
        raise CalibrationError(f"unknown export format {fmt!r}; use one of {', '.join(FORMATS)}")
    names = {
        "ros": [f"{stem}_left.yaml", f"{stem}_right.yaml"],
        "kalibr": [f"{stem}-camchain.yaml"],
        "opencv": ["intrinsics.yml", "extrinsics.yml"],
        "middlebury": ["calib.txt"],
    }[fmt]
    return [Path(out_dir) / name for name in names]


def export_calibration(
    cal: Calibration, fmt: str, out_dir: str | Path, stem: str = "calibration"
) -> list[Path]:
    """Write ``cal`` in format ``fmt`` into ``out_dir`` (files: :func:`export_paths`); returns
    the files written."""
    paths = export_paths(fmt, out_dir, stem)
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    if fmt == "ros":
        texts = [
            ros_camera_info("left", cal.image_size, cal.K1, cal.D1, cal.R1, cal.P1),
            ros_camera_info("right", cal.image_size, cal.K2, cal.D2, cal.R2, cal.P2),
        ]
    elif fmt == "kalibr":
        texts = [kalibr_camchain(cal)]
    elif fmt == "middlebury":
        texts = [middlebury_calib(cal)]
    else:
        texts = list(_opencv_files(cal))
    written = []
    for path, text in zip(paths, texts, strict=False):
        try:
            written.append(write_bytes_atomic(path, text))
        except OSError as exc:
            raise CalibrationError(
                f"cannot write {path} ({exc.strerror}); check the folder is writable"
            ) from None
    return written
