"""The compiled per-point passes give NumPy's results bit for bit, on a real surface: the
Middlebury cones' ground-truth disparity triangulated (300×200 pixels, 58,820 with a
disparity: a cloud with holes)."""

import cv2
import numpy as np
import pytest

from tests import paths
from vbfe.estimate.cell_passes import cell_medians, cell_sums, finite_rows, grid_cells
from vbfe.estimate.depth_image import DepthChangeImage
from vbfe.estimate.displacement import DisplacementGrid


def _cones_cloud() -> np.ndarray:
    """The cones scene as a cloud (metres-like units), unknown-disparity pixels NaN."""
    disparity = cv2.imread(
        str(paths.DATA / "middlebury_cones" / "disp0.png"), cv2.IMREAD_UNCHANGED
    ).astype(np.float32)
    disparity /= 4.0  # Middlebury 2003: 4 × disparity, 0 unknown
    h, w = disparity.shape
    q = np.float64([[1, 0, 0, -w / 2], [0, 1, 0, -h / 2], [0, 0, 0, 450.0], [0, 0, 1 / 0.16, 0]])
    points = cv2.reprojectImageTo3D(disparity, q).reshape(-1, 3)
    points[disparity.ravel() <= 0] = np.nan
    return points


def _numpy_cells(points, lo, size, cells):
    ij = np.floor((points[:, :2] - lo) / size).astype(np.int64)
    i, j = ij[:, 0], ij[:, 1]
    inside = (i >= 0) & (i < cells) & (j >= 0) & (j < cells)
    return np.where(inside, i * cells + j, 0), inside


def _numpy_medians(points, lo, size, cells, min_points):
    """Per-cell median z by one sort of every point by cell, then depth."""
    cell, inside = _numpy_cells(points, lo, size, cells)
    cell, z = cell[inside], points[inside, 2]
    depth = np.full(cells * cells, np.nan)
    order = np.lexsort((z, cell))
    cell, z = cell[order], z[order]
    start = np.concatenate([[0], np.flatnonzero(np.diff(cell)) + 1])
    count = np.diff(np.append(start, len(cell)))
    keep = count >= min_points
    mid, lower = start[keep] + count[keep] // 2, start[keep] + (count[keep] - 1) // 2
    depth[cell[start[keep]]] = (z[mid] + z[lower]) / 2
    return depth


@pytest.fixture(scope="module")
def cloud():
    return _cones_cloud()


def test_finite_rows_keep_the_rows_numpy_keeps(cloud):
    kept = finite_rows(cloud)
    expected = cloud[np.isfinite(cloud).all(axis=1)].astype(np.float64)
    assert len(kept) == 58_820 < len(cloud)  # the pixels with a disparity: the scene has holes
    assert kept.dtype == np.float64
    np.testing.assert_array_equal(kept, expected)
    np.testing.assert_array_equal(finite_rows(cloud.astype(np.float64)), expected)
    assert finite_rows(np.full((4, 3), np.inf)).shape == (0, 3)


@pytest.mark.parametrize("cells", [3, 16])
def test_cells_medians_and_sums_equal_numpy(cloud, cells):
    points = finite_rows(cloud)
    lo = np.percentile(points[:, :2], 10, axis=0)  # a grid inside the scene: points outside
    size = (np.percentile(points[:, :2], 90, axis=0) - lo) / cells
    cell, inside = grid_cells(points, lo, size, cells)
    expected_cell, expected_inside = _numpy_cells(points, lo, size, cells)
    assert 0 < inside.sum() < len(points)
    np.testing.assert_array_equal(inside, expected_inside)
    np.testing.assert_array_equal(cell, expected_cell)
    # depths rounded to few values: ties in every cell, even and odd counts
    for z in (points[:, 2], np.round(points[:, 2], 1)):
        tied = np.column_stack([points[:, :2], z])
        for min_points in (3, 1):
            np.testing.assert_array_equal(
                cell_medians(tied, lo, size, cells, min_points),
                _numpy_medians(tied, lo, size, cells, min_points),
            )
    rest = np.linspace(0.5, 1.5, cells * cells)
    total, count = cell_sums(points, lo, size, cells, rest)
    values = points[:, 2] - rest[expected_cell]
    n = cells * cells
    np.testing.assert_array_equal(total, np.bincount(cell[inside], values[inside], minlength=n))
    np.testing.assert_array_equal(count, np.bincount(cell[inside], minlength=n))


def test_a_sparse_cell_has_no_median_and_an_empty_cloud_none_at_all():
    points = np.array([[0.1, 0.1, 1.0], [0.15, 0.1, 2.0], [0.9, 0.9, 3.0]])
    depth = cell_medians(points, np.zeros(2), np.full(2, 0.5), 2, 2)
    np.testing.assert_array_equal(depth, [1.5, np.nan, np.nan, np.nan])
    empty = np.zeros((0, 3))
    assert np.isnan(cell_medians(empty, np.zeros(2), np.ones(2), 2, 1)).all()


def test_features_of_the_real_surface_against_itself_at_rest(cloud):
    """The preparation's grids read the cones at rest: no displacement, no depth change."""
    points = finite_rows(cloud)
    grid = DisplacementGrid(points)
    assert grid.peak_displacement_m(points) == 0.0
    image = DepthChangeImage(points, 8)
    total, count = image.sums_counts(points)
    assert count.sum() > 0.9 * len(points)  # the 2nd–98th percentile grid holds most points
    scale = np.abs(points[:, 2]).max()
    np.testing.assert_allclose(total / np.maximum(count, 1), 0.0, atol=1e-12 * scale)
