"""The one mapping table: every LiteGE error class has its own entry (no silent fallback to a
parent's code), client errors are 4xx, and codes are unique."""

from __future__ import annotations

import grpc

from litege_core import errors as core
from service import errors as svc
from service.problems import MAX_DETAIL_CHARS, PROBLEM_BASE_URI, problem_detail, problem_for


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


def test_problem_details_are_bounded():
    """Messages quoting request strings of any length are cut to a few hundred characters."""
    assert problem_detail(svc.UnknownModelError("short")) == "short"
    detail = problem_detail(svc.UnknownModelError("unknown model " + "m" * 30_000))
    assert len(detail) < MAX_DETAIL_CHARS + 50 and detail.endswith(
        f"({30_014 - MAX_DETAIL_CHARS} more characters)"
    )
