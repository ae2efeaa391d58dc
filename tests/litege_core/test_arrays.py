import numpy as np
import pytest

from litege_core.arrays import frozen


def test_frozen_copies_and_never_locks_the_callers_array():
    source = np.arange(6.0).reshape(2, 3)
    out = frozen(source, dtype=np.float32)
    assert out.dtype == np.float32 and out.flags.c_contiguous and not out.flags.writeable
    assert source.flags.writeable  # the caller's array is untouched
    source[0, 0] = 99.0
    assert out[0, 0] == 0.0
    with pytest.raises(ValueError):
        out[0, 0] = 1.0
