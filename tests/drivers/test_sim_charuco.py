"""The simulated ChArUco scene: OpenCV finds the board where the true geometry puts it."""

import cv2
import numpy as np
import pytest

from vbfe.common.errors import DeviceError
from vbfe.drivers.sim.charuco_scene import random_board_poses, render_board_views, visible_fraction
from vbfe.drivers.sim.optics import Optics
from vbfe.drivers.sim.rig import default_rig


@pytest.fixture(scope="module")
def board() -> cv2.aruco.CharucoBoard:
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_5X5_100)
    return cv2.aruco.CharucoBoard((9, 7), 0.003, 0.0022, dictionary)


def _true_corners(board, pose, camera, R=None, T=None):
    R_board, _ = cv2.Rodrigues(pose[0])
    points = np.asarray(board.getChessboardCorners()) @ R_board.T + pose[1]
    return camera.project(points, R, T)


def test_detected_corners_match_true_projection_with_distortion(board):
    rig = default_rig(distortion=True)
    R_board, _ = cv2.Rodrigues(np.radians([15.0, -10.0, 5.0]))
    rvec, _ = cv2.Rodrigues(R_board)
    pose = (rvec.ravel(), np.array([0.002, 0.001, 0.055]) - R_board @ np.array([0.0135, 0.0105, 0]))
    ((left, right),) = render_board_views(rig, board, [pose], rng=np.random.default_rng(0))
    assert left.shape == (rig.left.height, rig.left.width, 3) and left.dtype == np.uint8
    detector = cv2.aruco.CharucoDetector(board)
    for image, camera, R, T in ((left, rig.left, None, None), (right, rig.right, rig.R, rig.T)):
        corners, ids, _, _ = detector.detectBoard(image)
        assert ids is not None and len(ids) >= 40
        truth = _true_corners(board, pose, camera, R, T)[ids.ravel()]
        err = np.linalg.norm(corners.reshape(-1, 2) - truth, axis=1)
        assert err.mean() < 0.15 and err.max() < 0.4, (err.mean(), err.max())


def test_views_differ_between_eyes_by_the_baseline(board):
    rig = default_rig()
    pose = (np.zeros(3), np.array([-0.0135, -0.0105, 0.05]))
    ((left, right),) = render_board_views(
        rig, board, [pose], optics=Optics(noise_sigma=0.0), rng=np.random.default_rng(0)
    )
    detector = cv2.aruco.CharucoDetector(board)
    cl, il, _, _ = detector.detectBoard(left)
    cr, ir, _, _ = detector.detectBoard(right)
    common, a, b = np.intersect1d(il.ravel(), ir.ravel(), return_indices=True)
    disparity = cl.reshape(-1, 2)[a, 0] - cr.reshape(-1, 2)[b, 0]
    expected = rig.left.K[0, 0] * rig.baseline_m / 0.05
    assert len(common) > 30
    assert np.allclose(disparity, expected, atol=0.3)


def test_random_poses_keep_the_board_in_both_views(board):
    rig = default_rig(distortion=True)
    poses = random_board_poses(6, np.random.default_rng(3), rig=rig, board=board)
    assert len(poses) == 6
    distances = [np.linalg.norm(t) for _, t in poses]
    assert min(distances) > 0.03 and max(distances) < 0.1
    assert all(visible_fraction(rig, board, pose) >= 0.85 for pose in poses)
    views = render_board_views(rig, board, poses[:2], rng=np.random.default_rng(0))
    detector = cv2.aruco.CharucoDetector(board)
    assert all(detector.detectBoard(left)[1] is not None for left, _ in views)


def test_board_in_millimetres_is_refused(board):
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_5X5_100)
    board_mm = cv2.aruco.CharucoBoard((9, 7), 3.0, 2.2, dictionary)
    with pytest.raises(DeviceError, match="metres"):
        render_board_views(default_rig(), board_mm, [(np.zeros(3), np.array([0, 0, 0.05]))])
