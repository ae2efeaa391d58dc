import inspect

import litege_core.errors as errors


def _error_classes():
    return [
        obj
        for _, obj in inspect.getmembers(errors, inspect.isclass)
        if issubclass(obj, errors.LiteGEError)
    ]


def test_every_error_is_a_litege_error_with_a_unique_code():
    classes = _error_classes()
    assert len(classes) >= 10
    codes = [cls.code for cls in classes]
    assert len(codes) == len(set(codes)), "error codes must be unique (service maps them)"
    assert all(code.replace("-", "").isalpha() for code in codes)


def test_input_errors_are_value_errors_and_carry_details():
    exc = errors.FaceIndexError("bad index", index=7)
    assert isinstance(exc, ValueError) and isinstance(exc, errors.InputError)
    assert exc.details == {"index": 7} and str(exc) == "bad index"
    assert not issubclass(errors.ComputationError, errors.InputError)


def test_all_is_complete():
    assert sorted(errors.__all__) == sorted(cls.__name__ for cls in _error_classes())
