import numpy as np
import pytest

from litege_core.arrays import distinct_indices, distinct_indices_reference, frozen


def test_frozen_copies_and_never_locks_the_callers_array():
    source = np.arange(6.0).reshape(2, 3)
    out = frozen(source, dtype=np.float32)
    assert out.dtype == np.float32 and out.flags.c_contiguous and not out.flags.writeable
    assert source.flags.writeable  # the caller's array is untouched
    source[0, 0] = 99.0
    assert out[0, 0] == 0.0
    with pytest.raises(ValueError):
        out[0, 0] = 1.0


@pytest.mark.parametrize("count", [0, 1, 7, 100, 5000])
def test_distinct_indices_equal_the_unique_reference(count):
    rng = np.random.default_rng(count)
    size = 1000
    indices = rng.integers(0, size, count).reshape(-1, 1)  # any shape: read flat
    out = distinct_indices(indices, size)  # few indices: sorted; many: a mask
    assert out.dtype == np.int64
    np.testing.assert_array_equal(out, distinct_indices_reference(indices, size))
