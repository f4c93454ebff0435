"""Pose semantics (src/zcomp_cli/pose.py): rotation order, quaternions, placement."""

import numpy as np
import pytest

from zcomp_cli.errors import GeometryError, ManifestError
from zcomp_cli.pose import (
    Pose,
    euler_deg_to_matrix,
    matrix_to_quaternion,
    quaternion_to_matrix,
    rotation_aligning,
    transform_points,
)


def test_euler_order_is_rz_ry_rx():
    R = euler_deg_to_matrix(90, 90, 0)
    # x first: y -> z; then y: z -> x. So +y ends on +x.
    np.testing.assert_allclose(R @ [0, 1, 0], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(euler_deg_to_matrix(0, 0, 90) @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(euler_deg_to_matrix(0, 90, 0) @ [0, 0, 1], [1, 0, 0], atol=1e-12)


def test_quaternion_known_and_round_trip():
    s = np.sqrt(0.5)
    np.testing.assert_allclose(quaternion_to_matrix([s, 0, s, 0]), euler_deg_to_matrix(0, 90, 0), atol=1e-12)
    np.testing.assert_allclose(quaternion_to_matrix([2, 0, 0, 0]), np.eye(3))  # normalised
    rng = np.random.default_rng(1)
    for _ in range(20):
        R = euler_deg_to_matrix(*rng.uniform(-180, 180, 3))
        np.testing.assert_allclose(quaternion_to_matrix(matrix_to_quaternion(R)), R, atol=1e-9)
    # 180 degree rotations (trace -1) take the non-trace branches
    for axis in np.eye(3):
        R = 2 * np.outer(axis, axis) - np.eye(3)
        np.testing.assert_allclose(quaternion_to_matrix(matrix_to_quaternion(R)), R, atol=1e-9)


@pytest.mark.parametrize("q", [[0, 0, 0, 0], [np.nan, 0, 0, 1], [1e-20, 0, 0, 0]])
def test_quaternion_degenerate(q):
    with pytest.raises(ValueError):
        quaternion_to_matrix(q)


def test_object_to_camera_base_point_and_scale():
    bmin, bmax = np.array([1.0, 2.0, 3.0]), np.array([3.0, 4.0, 7.0])  # base (2, 2, 5)
    pose = Pose(position=(0.5, -1.0, -4.0), rotation=euler_deg_to_matrix(0, 45, 0), height=1.0)
    M = pose.object_to_camera(bmin, bmax)
    np.testing.assert_allclose(transform_points(M, [[2.0, 2.0, 5.0]])[0], [0.5, -1.0, -4.0], atol=1e-12)
    # height 1 m: the top centre is 1 m above the base along the object's up axis
    top = transform_points(M, [[2.0, 4.0, 5.0]])[0]
    np.testing.assert_allclose(top - [0.5, -1.0, -4.0], pose.up * 1.0, atol=1e-12)
    assert pose.uniform_scale(bmin, bmax) == pytest.approx(0.5)
    # plain scale
    assert Pose(position=(0, 0, -1), scale=2.0).uniform_scale(bmin, bmax) == 2.0


def test_up_axis_follows_rotation():
    np.testing.assert_allclose(Pose(position=(0, 0, -1)).up, [0, 1, 0])
    np.testing.assert_allclose(Pose(position=(0, 0, -1), rotation=euler_deg_to_matrix(90, 0, 0)).up, [0, 0, 1], atol=1e-12)


def test_height_of_flat_mesh_is_geometry_error():
    pose = Pose(position=(0, 0, -1), height=1.0)
    with pytest.raises(GeometryError):
        pose.object_to_camera([0, 0, 0], [1, 0, 1])


@pytest.mark.parametrize("kw", [dict(position=(0, 0)), dict(position=(0, np.nan, 0)), dict(position=(0, 0, -1), scale=0.0),
                                dict(position=(0, 0, -1), height=-1.0), dict(position=(0, 0, -1), rotation=np.diag([1, 1, -1])),
                                dict(position=(0, 0, -1), rotation=np.ones((3, 3)))])
def test_pose_validation(kw):
    with pytest.raises(ValueError):
        Pose(**kw)


def test_from_dict_round_trip_and_errors():
    p = Pose.from_dict({"position": [0, -1, -3], "rotation_deg": [10, 20, 30], "height": 0.9})
    q = Pose.from_dict(p.to_dict())
    np.testing.assert_allclose(q.rotation, p.rotation, atol=1e-9)
    assert q.height == 0.9 and q.position == (0.0, -1.0, -3.0)
    with pytest.raises(ManifestError) as ei:
        Pose.from_dict({"rotation_deg": [0, 0, 0], "quaternion": [1, 0, 0, 0], "bogus": 1}, where="renders[2].pose")
    msgs = ei.value.problems
    assert len(msgs) == 3 and all(m.startswith("renders[2].pose") for m in msgs)
    with pytest.raises(ManifestError, match="position"):
        Pose.from_dict({"position": [0, 0]})
    with pytest.raises(ManifestError):
        Pose.from_dict([0, 0, 0])


def test_rotation_aligning():
    for a, b in [([0, 1, 0], [0, 0, 1]), ([1, 0, 0], [-1, 0, 0]), ([0, 1, 0], [0, 1, 0])]:
        R = rotation_aligning(a, b)
        np.testing.assert_allclose(R @ a, b, atol=1e-9)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
        assert np.linalg.det(R) == pytest.approx(1.0)
