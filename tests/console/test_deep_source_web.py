"""Issue 22: every way a reward function reaches the static check gives an answer for any
text. A source nested past what can be checked is refused with "the reward function is nested
too deeply to check: ..." (with its line where known), never an HTTP 500; a source over the
size limit gets the one message for that (``SOURCE_TOO_LONG``) from the Validate API, saving,
the services and an imported archive alike."""

from __future__ import annotations

import html
import json

import pytest

from training.errors import RewardRejected
from training.interchange.archive import ArchiveError, reward_source
from training.sandbox.static import MAX_SOURCE_CHARS, SOURCE_TOO_LONG, TOO_DEEP
from training.services import rewards
from training.services.checks import check_reward

pytestmark = pytest.mark.django_db
URL = "/api/reward/validate"
FN = "def reward_function(params):\n    return "


def _elif_table(branches: int) -> str:
    lines = ["def reward_function(params):", "    x = params['steps']", "    if x == 0:"]
    lines.append("        return 0.0")
    for i in range(1, branches):
        lines += [f"    elif x == {i}:", f"        return {i}.0"]
    return "\n".join([*lines, "    return 1.0", ""])


#: Sources too deep to check, with the line the error names (None: Python's parser gave up).
TOO_DEEP_SOURCES = {
    "long_sum": (FN + "1.0" + " + 1" * 5000 + "\n", None),
    "nested_lambdas": (FN + "(" + "lambda: " * 2000 + "1.0)\n", 2),
    "elif_table_and_long_call_chain": (_elif_table(500) + "x = abs" + "(1)" * 5000 + "\n", None),
}
#: A 10 MB source: over the limit whatever it holds.
HUGE = "def reward_function(params):\n    return 1.0\n" + "#" * 10_000_000


@pytest.fixture(autouse=True)
def _room_for_validations(settings) -> None:
    settings.RACECRAFT_VALIDATIONS_PER_USER = 100
    settings.RACECRAFT_VALIDATIONS_PER_MINUTE = 100


def validate(client, source: str):
    body = json.dumps({"source": source, "track": "racecraft_oval"})
    return client.post(URL, body, content_type="application/json")


@pytest.mark.parametrize("source, line", TOO_DEEP_SOURCES.values(), ids=list(TOO_DEEP_SOURCES))
def test_the_validate_api_answers_a_deep_source(alice_client, source: str, line) -> None:
    response = validate(alice_client, source)
    assert response.status_code == 200, response.content[:500]
    body = response.json()
    assert body["status"] == "done" and body["ok"] is False
    (error,) = body["errors"]
    assert error["message"].startswith(f"{TOO_DEEP}: ") and error["lineNumber"] == line


def test_a_500_branch_elif_table_is_queued_like_any_function(alice_client) -> None:
    response = validate(alice_client, _elif_table(500))
    assert response.status_code == 202 and response.json()["status"] == "queued"


@pytest.mark.parametrize("source, line", TOO_DEEP_SOURCES.values(), ids=list(TOO_DEEP_SOURCES))
def test_the_reward_edit_page_answers_a_deep_source(
    alice_client, alice_model, source: str, line
) -> None:
    response = alice_client.post(f"/models/{alice_model.pk}/reward/", {"reward_function": source})
    assert response.status_code == 400
    page = html.unescape(response.content.decode())
    assert f"{TOO_DEEP}: " in page and "see the marked lines" in page
    errors = json.loads(page.split('id="reward-errors" type="application/json">')[1].split("<")[0])
    assert errors[0]["lineNumber"] == line
    alice_model.refresh_from_db()
    assert alice_model.reward_function != source  # nothing saved


@pytest.mark.parametrize("source, line", TOO_DEEP_SOURCES.values(), ids=list(TOO_DEEP_SOURCES))
def test_the_analysis_replay_answers_a_deep_source(
    alice_client, alice_model, source: str, line
) -> None:
    payload = {"iteration": 0, "episode": 0, "reward_function": source}
    response = alice_client.post(
        f"/models/{alice_model.pk}/analysis/replay/", payload, content_type="application/json"
    )
    assert response.status_code == 400
    assert response.json()["error"].lower().startswith(f"{TOO_DEEP}: ")


# ------------------------------------------------------------------------- source size
def test_a_10_mb_source_gets_the_one_message_from_the_validate_api(alice_client) -> None:
    response = validate(alice_client, HUGE)
    assert response.status_code == 413
    (error,) = response.json()["errors"]
    assert (error["type"], error["message"], error["field"]) == (
        "SYNTAX_ERROR",
        SOURCE_TOO_LONG,
        "source",
    )


def test_a_source_just_over_the_limit_gets_the_same_message_everywhere(
    alice, alice_client, alice_model
) -> None:
    source = "def reward_function(params):\n    return 1.0\n" + "#" * MAX_SOURCE_CHARS
    response = validate(alice_client, source)  # small enough to read: the static check's
    assert response.status_code == 200
    assert [e["message"] for e in response.json()["errors"]] == [SOURCE_TOO_LONG]
    page = alice_client.post(f"/models/{alice_model.pk}/reward/", {"reward_function": source})
    assert page.status_code == 400 and SOURCE_TOO_LONG in html.unescape(page.content.decode())
    check = rewards.reward_check_before_save(
        user=alice, source=source, tracks=[("racecraft_oval", "native")], how="passed"
    )
    assert check.status is rewards.RewardStatus.REFUSED
    assert isinstance(check.error, RewardRejected) and check.error.message == SOURCE_TOO_LONG


def test_the_services_give_the_one_message_for_a_10_mb_source(alice) -> None:
    for call in (
        lambda: check_reward(HUGE, "racecraft_oval"),
        lambda: rewards.reward_validation_start(
            user_id=alice.pk, source=HUGE, track_id="racecraft_oval", direction="native"
        ),
    ):
        with pytest.raises(RewardRejected) as caught:
            call()
        assert caught.value.message == SOURCE_TOO_LONG
        assert caught.value.errors[0]["type"] == "SYNTAX_ERROR"
    result = rewards.reward_validation_run(source=HUGE, track_id="racecraft_oval", direction="cw")
    assert [e["message"] for e in result["errors"]] == [SOURCE_TOO_LONG]
    with pytest.raises(ArchiveError) as refused:
        reward_source({"reward_function.py": HUGE.encode()}, "reward_function.py")
    assert str(refused.value) == f"reward_function.py: {SOURCE_TOO_LONG}"


def test_a_request_body_nested_too_deeply_is_refused_clearly(alice_client, alice_model) -> None:
    deep = "[" * 100_000 + "]" * 100_000
    response = alice_client.post(URL, deep, content_type="application/json")
    assert response.status_code == 400
    assert (
        response.json()["errors"][0]["message"] == "The request body is nested too deeply to read."
    )
    replay = alice_client.post(
        f"/models/{alice_model.pk}/analysis/replay/", deep, content_type="application/json"
    )
    assert replay.status_code == 400 and "reward_function" in replay.json()["error"]
