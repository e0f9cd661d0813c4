"""One rule for the rectified camera matrix (issue 56): with the same focal lengths and
principal points the joint and the fixed-intrinsics solves rectify to the same f, whatever
distortion each found at the image border (beyond the board views, where weaker views leave it
poorly determined)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from vbfe.calib.rectify import UNSCALED, rectified_fractions, stereo_rectify

SIZE = (640, 480)
# the distortion of the barrel endoscope's 7x7 render as the joint solve and the solve with
# each eye's intrinsics from 10 other views found it (left, right): k1, k2 and k3 differ
JOINT = (np.array([-0.2992, 0.0773, 0, 0, 0.0025]), np.array([-0.2901, 0.0704, 0, 0, 0]))
FIXED = (
    np.array([-0.3009, 0.0831, 0, -0.0001, -0.0036]),
    np.array([-0.2903, 0.07, -0.0001, -0.0001, -0.0001]),
)


def _rectified(D: tuple[np.ndarray, np.ndarray], alpha: float):
    K1 = np.array([[457.0, 0.0, 277.5], [0.0, 435.0, 242.0], [0.0, 0.0, 1.0]])
    K2 = K1.copy()
    K2[0, 2] = 362.5
    axis = np.array([0.2, 1.0, 0.1]) / np.linalg.norm([0.2, 1.0, 0.1])
    R = cv2.Rodrigues(np.radians(0.7) * axis)[0]
    rect = stereo_rectify(K1, D[0], K2, D[1], SIZE, R, np.array([-0.006, 0, 0]), alpha, True)
    return K1, K2, rect


def test_the_rectified_camera_depends_on_the_intrinsics_not_the_border_distortion():
    _, _, cropped_joint = _rectified(JOINT, 0.0)
    _, _, cropped_fixed = _rectified(FIXED, 0.0)  # stereoRectify's crop to valid pixels
    assert abs(cropped_fixed.P1[0, 0] / cropped_joint.P1[0, 0] - 1) > 2e-3  # measured 0.33 %
    K1, K2, joint = _rectified(JOINT, UNSCALED)
    _, _, fixed = _rectified(FIXED, UNSCALED)
    for name in ("P1", "P2", "Q"):
        np.testing.assert_allclose(getattr(joint, name), getattr(fixed, name), rtol=1e-12)
    assert joint.P1[0, 0] == joint.P1[1, 1] == 435.0  # the eyes' fy
    assert -joint.P2[0, 3] / joint.P2[0, 0] == pytest.approx(0.006, rel=1e-12)
    rays = [P[:, :3] @ Rk[:, 2] for P, Rk in ((joint.P1, joint.R1), (joint.P2, joint.R2))]
    landed = np.mean([ray[:2] / ray[2] for ray in rays], axis=0)  # zero disparity: their mean
    assert landed == pytest.approx((K1[:2, 2] + K2[:2, 2]) / 2, abs=1e-9)
    for K, D, R, P in ((K1, JOINT[0], joint.R1, joint.P1), (K2, JOINT[1], joint.R2, joint.P2)):
        assert min(rectified_fractions(K, D, R, P, SIZE)) > 0.75  # alpha 0 kept 0.69
