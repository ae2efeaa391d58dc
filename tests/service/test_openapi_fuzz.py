"""Schemathesis against the served OpenAPI schema over real HTTP: whatever it generates, the
service answers without a 5xx (and problems are RFC 9457 JSON)."""

from __future__ import annotations

import hypothesis
import pytest
import schemathesis
from schemathesis.checks import not_a_server_error

from litege_core.matching.model import MatchingModel

MAX_EXAMPLES = 30


@pytest.fixture(scope="module")
def fuzz_service(live_service_factory):
    return live_service_factory(
        max_upload_bytes=256 * 1024,
        max_queries=20_000,
        matching=MatchingModel.tiny_random(0),
    )


@pytest.fixture(scope="module")
def api_schema(fuzz_service):
    return schemathesis.openapi.from_url(f"{fuzz_service.base_url}/openapi.json")


def test_no_server_errors(api_schema):
    """Every operation, ``MAX_EXAMPLES`` generated cases each (deterministic)."""
    operations = [result.ok() for result in api_schema.get_all_operations()]
    assert {op.path for op in operations} >= {"/shapes", "/geodesic", "/paths", "/correspondences"}
    for operation in operations:

        @hypothesis.given(case=operation.as_strategy())
        @hypothesis.settings(
            max_examples=MAX_EXAMPLES,
            deadline=None,
            suppress_health_check=list(hypothesis.HealthCheck),
            derandomize=True,
            database=None,
        )
        def check(case):
            response = case.call()
            case.validate_response(response, checks=(not_a_server_error,))
            if response.status_code >= 400:
                content_type = response.headers.get("content-type", "")
                if isinstance(content_type, list):  # schemathesis' own header mapping
                    content_type = content_type[0]
                assert content_type.startswith("application/problem+json"), response.text

        check()
