import numpy as np
import pytest

from litege_core.errors import (
    ArrayShapeError,
    DegenerateShapeError,
    EmptyShapeError,
    FaceIndexError,
    NonFiniteError,
    NonTriangularFacesError,
    ShapeTooLargeError,
)
from litege_core.validate import ShapeLimits, validate_arrays, validate_faces, validate_vertices

TRIANGLE = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
FACE = np.array([[0, 1, 2]])


def test_valid_mesh_is_normalized_to_float64_and_int64():
    vertices, faces = validate_arrays(TRIANGLE.astype(np.float32), FACE.astype(np.int32))
    assert vertices.dtype == np.float64 and faces.dtype == np.int64
    assert vertices.flags.c_contiguous and faces.flags.c_contiguous


def test_integral_float_faces_are_accepted():
    _, faces = validate_arrays(TRIANGLE, FACE.astype(np.float64))
    assert faces.dtype == np.int64


@pytest.mark.parametrize(
    ("vertices", "error"),
    [
        (np.zeros((0, 3)), EmptyShapeError),
        ([], EmptyShapeError),
        (np.zeros((4, 2)), ArrayShapeError),
        (np.zeros(3), ArrayShapeError),
        (np.zeros((2, 3, 1)), ArrayShapeError),
        (np.array([["a", "b", "c"]]), ArrayShapeError),
        ([[0, 0, 0], [1, 1]], ArrayShapeError),
        (np.array([[0, 0, np.nan], [1, 1, 1]]), NonFiniteError),
        (np.array([[0, 0, 0], [1, np.inf, 1]]), NonFiniteError),
    ],
)
def test_bad_vertices(vertices, error):
    with pytest.raises(error):
        validate_vertices(vertices)


def test_non_finite_reports_first_bad_vertex():
    with pytest.raises(NonFiniteError) as info:
        validate_vertices(np.array([[0, 0, 0], [0, 0, 0], [np.nan, 0, 0]]))
    assert info.value.details == {"first_index": 2, "count": 1}


def test_too_many_vertices():
    with pytest.raises(ShapeTooLargeError):
        validate_vertices(np.zeros((11, 3)), ShapeLimits(max_vertices=10))


@pytest.mark.parametrize(
    ("faces", "error"),
    [
        (np.zeros((0, 3), dtype=int), EmptyShapeError),
        (np.array([[0, 1, 2, 0]]), NonTriangularFacesError),
        (np.array([[0, 1]]), NonTriangularFacesError),
        ([[0, 1, 2], [0, 1]], NonTriangularFacesError),
        (np.array([0, 1, 2]), ArrayShapeError),
        (np.array([[0.5, 1, 2]]), ArrayShapeError),
        (np.array([["0", "1", "2"]]), ArrayShapeError),
        (np.array([[0, 1, 3]]), FaceIndexError),
        (np.array([[0, -1, 2]]), FaceIndexError),
    ],
)
def test_bad_faces(faces, error):
    with pytest.raises(error):
        validate_faces(faces, 3)


def test_face_index_error_names_the_index():
    with pytest.raises(FaceIndexError) as info:
        validate_faces(np.array([[0, 1, 99]]), 3)
    assert info.value.details["index"] == 99 and "99" in str(info.value)


def test_too_many_faces():
    with pytest.raises(ShapeTooLargeError):
        validate_faces(np.tile(FACE, (5, 1)), 3, ShapeLimits(max_faces=4))


def test_zero_area_mesh_is_degenerate():
    collinear = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])
    with pytest.raises(DegenerateShapeError):
        validate_arrays(collinear, FACE)


def test_coincident_point_cloud_is_degenerate():
    with pytest.raises(DegenerateShapeError):
        validate_arrays(np.ones((5, 3)), None)


def test_huge_coordinates_are_refused():
    from litege_core.errors import CoordinateRangeError

    vertices = np.array([[0, 0, 0], [1e200, 0, 0], [0, 1, 0]], dtype=float)
    with pytest.raises(CoordinateRangeError, match="rescale"):
        validate_arrays(vertices, None)
    validate_arrays(vertices / 1e190, None)  # 1e10 is fine


def test_microscopic_shapes_are_degenerate():
    vertices = np.array([[0, 0, 0], [1e-12, 0, 0], [0, 1e-12, 0]], dtype=float)
    with pytest.raises(DegenerateShapeError, match="rescale"):
        validate_arrays(vertices, [[0, 1, 2]])
    with pytest.raises(DegenerateShapeError, match="rescale"):
        validate_arrays(vertices, None)


def test_face_indices_beyond_int64():
    from litege_core.errors import FaceIndexError

    with pytest.raises(FaceIndexError, match="int64"):
        validate_faces([[0, 1, 2**70]], 3)
