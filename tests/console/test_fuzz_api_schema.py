"""Schema-driven fuzzing of the JSON API (schemathesis, bounded examples): requests generated
from console/openapi.json, served by the real Django application as a signed-in user with a
CSRF token. No answer is a server error, every status is one the description lists, and the
description itself is served and is valid OpenAPI."""

from __future__ import annotations

import json

import pytest
import schemathesis
from django.contrib.auth import get_user_model
from django.core.wsgi import get_wsgi_application
from django.test import Client
from hypothesis import HealthCheck, settings
from schemathesis.checks import not_a_server_error
from schemathesis.specs.openapi.checks import (
    content_type_conformance,
    response_schema_conformance,
    status_code_conformance,
)

from console.views.api import OPENAPI_PATH

pytestmark = [pytest.mark.django_db(transaction=True), pytest.mark.slow]

schema = schemathesis.openapi.from_dict(json.loads(OPENAPI_PATH.read_text()))
schema.app = get_wsgi_application()  # requests go to the real Django app, in-process
CSRF = "f" * 32  # any well-formed token: the cookie and the header must agree


@pytest.fixture
def signed_in(tmp_path, settings):
    settings.STORE_DIR = tmp_path / "store"
    settings.ALLOWED_HOSTS = ["localhost", "testserver"]
    user = get_user_model().objects.create_user("fuzzer", password="pw-fuzzer-123")
    client = Client()
    client.force_login(user)
    session = client.cookies[settings.SESSION_COOKIE_NAME].value
    return {settings.SESSION_COOKIE_NAME: session, "csrftoken": CSRF}


def test_the_description_is_served(client):
    response = client.get("/api/openapi.json")
    assert response.status_code == 200
    assert response.json()["paths"].keys() >= {"/api/reward/validate"}


@schema.parametrize()
@settings(max_examples=25, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow,
                                 HealthCheck.filter_too_much])  # fmt: skip
def test_the_api_never_answers_500(case, signed_in):
    response = case.call(headers={"X-CSRFToken": CSRF}, cookies=signed_in)
    assert response.status_code not in (302, 403), "signed in, with a CSRF token"
    case.validate_response(
        response,
        checks=[not_a_server_error, status_code_conformance, content_type_conformance,
                response_schema_conformance],
    )  # fmt: skip
