"""The one mapping table: every LiteGE error class has its own entry (no silent fallback to a
parent's code), client errors are 4xx, and codes are unique."""

from __future__ import annotations

import grpc

from litege_core import errors as core
from service import errors as svc
from service.problems import PROBLEM_BASE_URI, problem_for


def _all_error_classes() -> list[type[core.LiteGEError]]:
    seen, stack = [], [core.LiteGEError]
    while stack:
        cls = stack.pop()
        seen.append(cls)
        stack.extend(cls.__subclasses__())
    return seen


def test_every_error_class_has_its_own_entry():
    classes = _all_error_classes()
    assert len(classes) > 20
    codes = set()
    for cls in classes:
        kind = problem_for(cls("x"))
        assert kind.code == cls.code, f"{cls.__name__} falls back to {kind.code}"
        assert kind.type_uri == PROBLEM_BASE_URI + cls.code
        codes.add(kind.code)
        if issubclass(cls, core.InputError):
            assert 400 <= kind.http_status < 500
            assert kind.grpc_status in (
                grpc.StatusCode.INVALID_ARGUMENT,
                grpc.StatusCode.RESOURCE_EXHAUSTED,
            )
    assert len(codes) == len(classes), "codes must be unique"


def test_overload_status_follows_the_error():
    assert problem_for(svc.OverloadedError("full")).http_status == 503
    assert problem_for(svc.OverloadedError("busy", status=429)).http_status == 429
