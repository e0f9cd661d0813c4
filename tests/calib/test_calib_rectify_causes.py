"""Every refusal of the rectification names only causes its own measurement supports and only
remedies that, recomputed, reach the limit (issue 56): an SD endoscope's geometry (640x480,
fx/fy 1.05, k1 -0.3) with each cause in turn, the refusal's remedies applied and measured."""

from __future__ import annotations

import re

import cv2
import numpy as np
import pytest

from vbfe.calib.calibration import Calibration
from vbfe.calib.gates import FAIL, GateLimits, stereo_gates
from vbfe.calib.rectify import rectify, stereo_rectify, usable, worst_fraction

SIZE = (640, 480)
D = np.array([-0.3, 0.08, 0.0, 0.0, 0.0])


def _camera(cx: float) -> np.ndarray:
    return np.array([[457.0, 0.0, cx], [0.0, 435.0, 242.0], [0.0, 0.0, 1.0]])


def _calibration(
    offset_px: float, angle_deg: float, zero_disparity: str, limit: float, D2: np.ndarray = D
) -> Calibration:
    """The pair rectified as ``calibrate stereo`` does (the gate's limit decides the search)."""
    K1, K2 = _camera(320.0 - offset_px / 2), _camera(320.0 + offset_px / 2)
    R = cv2.Rodrigues(np.radians(angle_deg) * np.array([0.0, 1.0, 0.0]))[0]
    T = np.array([-0.005, 0.0, 0.0])
    rect = rectify(K1, D, K2, D2, SIZE, R, T, 0.0, zero_disparity, limit)
    return Calibration(
        K1=K1, D1=D, K2=K2, D2=D2, R=R, T=T, R1=rect.R1, R2=rect.R2, P1=rect.P1, P2=rect.P2,
        Q=rect.Q, image_size=SIZE, rms_stereo_px=0.2, info={"rectify_alpha": rect.alpha},
    )  # fmt: skip


def _share(cal: Calibration, alpha: float, zero: bool, D2: np.ndarray | None = None) -> float:
    D2 = cal.D2 if D2 is None else D2
    rect = stereo_rectify(cal.K1, cal.D1, cal.K2, D2, SIZE, cal.R, cal.T, alpha, zero)
    return worst_fraction(cal.K1, cal.D1, cal.K2, D2, rect, SIZE) if usable(rect) else 0.0


def _refusal(cal: Calibration, limit: float) -> str:
    gates = stereo_gates(cal, GateLimits(min_rectified_fraction=limit, max_rms_px=1.0))
    failed = [g for g in gates if g.verdict == FAIL]
    assert failed and failed[-1].name == "rectified image kept"
    return failed[-1].problem or ""


def _check_claims(cal: Calibration, message: str, limit: float) -> list[str]:
    """Each remedy the message names, applied: its share recomputed equals the one stated,
    reaches the limit and differs from the share as solved. Returns the remedies."""
    alpha = float(cal.info["rectify_alpha"])
    zero = abs(cal.doffs) < 1e-6
    solved = _share(cal, alpha, zero)
    named = []
    option = r"--[\w-]+(?: (?:off|on|[\d.]+))?"
    for said, stated in re.findall(rf"((?:{option} ?)+) \(recomputed: (\d+) %\)", message):
        values = dict(re.findall(r"--([\w-]+) ?((?:off|on|[\d.]+)?)", said))
        D2 = np.where(np.arange(5) == 4, 0.0, cal.D2) if "fix-k3" in values else None
        share = _share(
            cal,
            float(values.get("rectify-alpha", alpha)),
            {"off": False, "on": True}.get(values.get("zero-disparity", ""), zero),
            D2,
        )
        assert share * 100 == pytest.approx(float(stated), abs=1.0)
        assert share >= limit > solved and share - solved > 0.01
        named.append(said.strip())
    return named


def _measured(message: str, what: str) -> float:
    found = re.search(rf"(\d+) % {what}", message)
    assert found, message
    return float(found[1]) / 100


def test_offset_with_zero_disparity_forced_names_zero_disparity_off():
    # 200 px apart: forced zero disparity keeps at best 77 % over free scalings, without it 84 %
    cal = _calibration(200.0, 0.7, "on", 0.8)
    message = _refusal(cal, 0.8)
    assert "the cause is the offset between the eyes' principal points" in message
    assert "rotation" not in message.split("(measured")[0]  # 0.7 deg does not crop
    assert _check_claims(cal, message, 0.8)[0].startswith("--zero-disparity off")
    assert _measured(message, "without zero disparity") >= _measured(message, "as solved") + 0.05


def test_a_rotation_no_option_removes_is_named_without_a_remedy_it_rules_out():
    limit = 0.8
    cal = _calibration(0.0, 20.0, "auto", limit)
    message = _refusal(cal, limit)
    assert "the cause is the rotation between the eyes" in message
    without = _measured(message, "without the rotation between the eyes")
    assert without >= _measured(message, "as solved") + 0.05
    _check_claims(cal, message, limit)  # whatever it offers, recomputed, reaches the limit
    if "no rectification option keeps" in message:  # then no free scaling reaches it either
        assert max(_share(cal, a / 10, z) for a in range(11) for z in (True, False)) < limit


def test_a_crop_no_single_cause_explains_names_none():
    limit = 0.97  # above what any rectification of barrel distortion keeps
    cal = _calibration(0.0, 0.7, "auto", limit, D2=D * 1.02)
    message = _refusal(cal, limit)
    solved = _measured(message, "as solved")
    for what in ("without zero disparity", "without distortion", "without the rotation"):
        found = re.search(rf"(\d+) % {what}", message)
        if found and float(found[1]) / 100 >= solved + 0.05:
            assert "the cause is" in message
            break
    else:
        assert message.startswith("rectified") and "no single cause" in message
    assert not _check_claims(cal, message, limit) and "no rectification option keeps" in message


def test_the_pairs_are_not_blamed_when_zero_disparity_off_puts_a_principal_point_outside():
    cal = _calibration(500.0, 0.7, "off", 0.5)  # principal points 500 px apart
    assert cal.doffs > 600 and not (0 <= cal.P1[0, 2] < 640 and 0 <= cal.P2[0, 2] < 640)
    gates = {g.name: g for g in stereo_gates(cal, GateLimits(min_rectified_fraction=0.5))}
    assert gates["rectified principal points"].verdict == "pass"
    assert gates["rectified image kept"].verdict == "pass"  # the crop is what is judged
