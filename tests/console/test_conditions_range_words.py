"""What the "Outside world" fieldset says of ranges is what it allows (issue 51's loose end):
a range may be anything within the parameter's widest, narrower *or wider* than the training
default; beyond the widest it is refused, in those words. (Ambient light: widest -50 to 50,
default -25 to 25 gray levels.)"""

from __future__ import annotations

import pytest

from tests.console.test_model_views import create_data, reward_passed  # noqa: F401 - fixture
from training.models import RacingModel

pytestmark = pytest.mark.django_db


def test_a_range_wider_than_the_default_within_the_widest_is_kept(
    alice_client,
    store_dir,
    reward_passed,  # noqa: F811 - the fixture imported above
) -> None:
    data = create_data(cond_light="on", cond_light_brightness_low="-45",
                       cond_light_brightness_high="50")  # fmt: skip
    response = alice_client.post("/models/new/", data)
    assert response.status_code == 302, response.content.decode()[:2000]
    light = RacingModel.objects.get().conditions["families"]["light"]
    assert light["brightness"] == [-45.0, 50.0]  # wider than the default -25 to 25


@pytest.mark.parametrize(
    ("field", "value", "bound"), [("low", "-51", "at least -50"), ("high", "60", "at most 50")]
)
def test_beyond_the_widest_is_refused_in_words_that_say_what_is_allowed(
    alice_client, store_dir, field, value, bound
) -> None:
    data = create_data(cond_light="on", **{f"cond_light_brightness_{field}": value})
    response = alice_client.post("/models/new/", data)
    assert response.status_code == 400 and not RacingModel.objects.exists()
    page = response.content.decode().replace("&#x27;", "'")
    assert (
        f"Ambient light: {bound} (a range may be anything within its widest, -50 to 50, "
        "narrower or wider than the default -25 to 25)."
    ) in page
    assert "not widened" not in page
