"""The exact calibration of a simulated rig (what a perfect calibration would find)."""

from __future__ import annotations

import cv2
import numpy as np

from vbfe.calib import Calibration
from vbfe.drivers.sim.rig import StereoRig


def calibration_from_rig(rig: StereoRig) -> Calibration:
    """The exact calibration of a simulated :class:`~vbfe.drivers.sim.rig.StereoRig`.

    Rectification comes from ``cv2.stereoRectify`` on the true intrinsics and pose (zero
    disparity at infinity, no cropping), so a distortion-free parallel rig rectifies to itself
    and its rendered truth maps share the rectified pixel grid.
    """
    size = (rig.left.width, rig.left.height)
    R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(
        rig.left.K,
        rig.left.dist,
        rig.right.K,
        rig.right.dist,
        size,
        np.asarray(rig.R, np.float64),
        np.asarray(rig.T, np.float64).reshape(3, 1),
        flags=cv2.CALIB_ZERO_DISPARITY,
        alpha=0,
    )
    return Calibration(
        K1=rig.left.K,
        D1=rig.left.dist,
        K2=rig.right.K,
        D2=rig.right.dist,
        R=rig.R,
        T=rig.T,
        R1=R1,
        R2=R2,
        P1=P1,
        P2=P2,
        Q=Q,
        image_size=size,
        K_proj=rig.projector.K,
        D_proj=rig.projector.dist,
        R_proj=rig.R_proj,
        T_proj=rig.T_proj,
        projector_size=(rig.projector.width, rig.projector.height),
        info={"source": "simulated bench truth"},
    )
