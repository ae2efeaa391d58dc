"""ShapeRecord: the small half of a registration that a cache stores, and
Predictor.restore, which rebuilds the state from it without recomputing the descriptor."""

import numpy as np
import pytest
import torch

from litege_core.errors import ArtifactError, InputError
from litege_core.learned import ShapeRecord
from litege_core.shape import Shape


def test_restore_equals_register(toy_predictor, blob):
    shape = blob(3)
    registered = toy_predictor.register(shape, seed=5)
    record = ShapeRecord.from_arrays(registered.record.to_arrays())
    restored = toy_predictor.restore(shape, record)
    assert restored.shape_id == registered.shape_id
    assert restored.record.seed == 5
    assert restored.transform.allclose(registered.transform)
    np.testing.assert_array_equal(restored.descriptor, registered.descriptor)
    torch.testing.assert_close(
        toy_predictor.point_table(restored), toy_predictor.point_table(registered)
    )
    np.testing.assert_array_equal(
        toy_predictor.distances(restored, [0, 7, 30]),
        toy_predictor.distances(registered, [0, 7, 30]),
    )


def test_restore_many_matches_restore(toy_predictor, blob):
    shapes = [blob(1), blob(2, subdivisions=2)]
    records = [s.record for s in toy_predictor.register_many(shapes)]
    many = toy_predictor.restore_many(shapes, records)
    for shape, record, state in zip(shapes, records, many, strict=True):
        one = toy_predictor.restore(shape, record)
        torch.testing.assert_close(toy_predictor.point_table(one), toy_predictor.point_table(state))


def test_record_arrays_are_plain_numeric(toy_predictor, blob):
    arrays = toy_predictor.register(blob(1)).record.to_arrays()
    assert all(isinstance(a, np.ndarray) and a.dtype != object for a in arrays.values())


def test_record_of_another_shape_is_refused(toy_predictor, blob):
    record = toy_predictor.register(blob(1)).record
    with pytest.raises(InputError, match="does not belong"):
        toy_predictor.restore(blob(2), record)


def test_record_of_another_bundle_is_refused(toy_predictor, blob):
    shape = blob(1)
    arrays = toy_predictor.register(shape).record.to_arrays()
    arrays["bundle_hash"] = np.frombuffer(b"0" * 64, dtype=np.uint8).copy()
    with pytest.raises(InputError, match="another model bundle"):
        toy_predictor.restore(shape, ShapeRecord.from_arrays(arrays))


@pytest.mark.parametrize(
    "corrupt",
    [
        lambda a: a.pop("descriptor"),
        lambda a: a.__setitem__("scale", np.array([-1.0])),
        lambda a: a.__setitem__("rotation", np.eye(4)),
        lambda a: a.__setitem__("descriptor", np.array([np.nan, 1.0])),
        lambda a: a.__setitem__("shape_id", np.array([255, 254], dtype=np.uint8)),
    ],
)
def test_malformed_record_arrays_raise_artifact_error(toy_predictor, blob, corrupt):
    arrays = toy_predictor.register(blob(1)).record.to_arrays()
    corrupt(arrays)
    with pytest.raises(ArtifactError, match="malformed shape record"):
        ShapeRecord.from_arrays(arrays)


def test_restore_rejects_wrong_descriptor_length(toy_predictor, blob):
    shape = blob(1)
    arrays = toy_predictor.register(shape).record.to_arrays()
    arrays["descriptor"] = np.zeros(9, dtype=np.float32)
    with pytest.raises(InputError):
        toy_predictor.restore(shape, ShapeRecord.from_arrays(arrays))


def test_restore_rejects_non_shapes(toy_predictor, blob):
    record = toy_predictor.register(blob(1)).record
    with pytest.raises(InputError):
        toy_predictor.restore("not a shape", record)  # type: ignore[arg-type]
    assert isinstance(blob(1), Shape)
