"""FANUC W/P/R (= URDF rpy): R = Rz(r) Ry(p) Rx(w), fixed axes; exact at the gimbal lock."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from calib.wpr import matrix_from_rpy, pose_from_xyzwpr, rpy_from_matrix, xyzwpr_from_pose


def test_wpr_is_fixed_axis_xyz_w_first() -> None:
    # w = 90 then r = 90 about the fixed axes: x -> x -> y, y -> z -> z
    R = pose_from_xyzwpr([0, 0, 0, 90.0, 0, 90.0])[0, :3, :3]
    assert np.allclose(R @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    assert np.allclose(R @ [0, 1, 0], [0, 0, 1], atol=1e-15)
    # the other order, Rx(w) Rz(r), would send x -> y -> z
    R_other = Rotation.from_euler("x", 90, degrees=True) * Rotation.from_euler(
        "z", 90, degrees=True
    )
    assert np.allclose(R_other.as_matrix() @ [1, 0, 0], [0, 0, 1], atol=1e-15)


def test_wpr_matches_scipy_extrinsic_xyz() -> None:
    rng = np.random.default_rng(0)
    wpr = rng.uniform(-180, 180, (500, 3))
    wpr[:, 1] /= 2.0
    xyz = rng.uniform(-2000, 2000, (500, 3))
    T = pose_from_xyzwpr(np.hstack([xyz, wpr]))
    assert np.allclose(T[:, :3, :3], Rotation.from_euler("xyz", wpr, degrees=True).as_matrix())
    assert np.array_equal(T[:, :3, 3], xyz)
    back = xyzwpr_from_pose(T)
    assert np.allclose(back, np.hstack([xyz, wpr]), atol=1e-9)


def test_angles_rebuild_the_matrix_at_and_near_the_gimbal_lock() -> None:
    rng = np.random.default_rng(1)
    for pitch in (np.pi / 2, -np.pi / 2, np.pi / 2 - 1e-9, -np.pi / 2 + 3e-7, 0.3):
        rpy = np.column_stack(
            [rng.uniform(-3, 3, 200), np.full(200, pitch), rng.uniform(-3, 3, 200)]
        )
        R = matrix_from_rpy(rpy)
        assert np.abs(matrix_from_rpy(rpy_from_matrix(R)) - R).max() < 4e-15
    # random rotations (scipy's, not ours)
    R = Rotation.random(1000, random_state=2).as_matrix()
    assert np.abs(matrix_from_rpy(rpy_from_matrix(R)) - R).max() < 4e-15
