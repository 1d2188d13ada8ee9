"""A race's layout on a track (issue 13): ``/tracks/<id>/race.png`` draws the boxes or bot cars
where an episode starts them, with the wizard's settings, and answers bad settings with a 400
in words; the Tracks page's form shows it, or its errors on their fields."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from django.test import Client

from console import tracks
from racing.drawing import BOT_RGB, BOX_RGB

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
URL = "/tracks/racecraft_oval/race.png"

pytestmark = pytest.mark.django_db


@pytest.fixture(autouse=True)
def fresh_cache():
    tracks.preview_cache_clear()
    yield
    tracks.preview_cache_clear()


def patches(png: bytes, rgb: tuple[int, int, int]) -> int:
    """How many separate patches of (nearly) ``rgb`` the picture holds."""
    image = cv2.cvtColor(cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR),
                         cv2.COLOR_BGR2RGB)  # fmt: skip
    mask = (np.abs(image.astype(int) - np.array(rgb)).sum(axis=2) < 30).astype(np.uint8)
    count, _, stats, _ = cv2.connectedComponentsWithStats(mask)
    return sum(1 for s in stats[1:] if s[4] >= 4)


def test_the_boxes_and_bots_of_a_race_are_drawn_on_the_track(client: Client) -> None:
    boxes = client.get(URL, {"race_type": "OBJECT_AVOIDANCE", "number_of_objects": "4"})
    assert boxes.status_code == 200 and boxes["Content-Type"] == "image/png"
    assert boxes.content.startswith(PNG_SIGNATURE) and patches(boxes.content, BOX_RGB) == 4
    fixed = client.get(URL, {"race_type": "OBJECT_AVOIDANCE",
                             "object_positions": "0.2,1;0.5,-1"})  # fmt: skip
    assert patches(fixed.content, BOX_RGB) == 2
    bots = client.get(URL, {"race_type": "HEAD_TO_BOT", "number_of_bots": "5", "direction": "cw"})
    assert bots.status_code == 200 and patches(bots.content, BOT_RGB) == 5
    again = client.get(URL, {"race_type": "HEAD_TO_BOT", "number_of_bots": "5", "direction": "cw"},
                       headers={"if-none-match": bots["ETag"]})  # fmt: skip
    assert again.status_code == 304


def test_a_random_placement_shows_the_draw_asked_for(client: Client) -> None:
    query = {"race_type": "OBJECT_AVOIDANCE", "object_placement": "random", "seed": "1"}
    first = client.get(URL, query).content
    assert client.get(URL, query).content == first
    assert client.get(URL, {**query, "seed": "2"}).content != first


@pytest.mark.parametrize(
    "query, words",
    [
        ({}, "Race type: This field is required."),
        ({"race_type": "OBJECT_AVOIDANCE", "number_of_objects": "many"},
         "Number of boxes: Enter a whole number."),
        ({"race_type": "OBJECT_AVOIDANCE", "number_of_objects": "9"}, "1 to 6"),
        ({"race_type": "OBJECT_AVOIDANCE", "object_positions": "0.5"}, "fraction,lane"),
        ({"race_type": "OBJECT_AVOIDANCE", "object_positions": "0.3,1;0.35,-1"},
         "closer than 0.13"),
        ({"race_type": "HEAD_TO_BOT", "bot_speed": "9"}, "0.2-6.0 m/s"),
        ({"race_type": "HEAD_TO_BOT", "direction": "sideways"}, "Direction: Select a valid"),
        ({"race_type": "OBJECT_AVOIDANCE", "seed": "-1"}, "Random draw:"),
    ],
)  # fmt: skip
def test_bad_settings_get_a_400_that_says_what_is_wrong(client: Client, query, words) -> None:
    response = client.get(URL, query)
    assert response.status_code == 400
    assert response["Content-Type"].startswith("text/plain")
    assert words in response.content.decode()


def test_an_unknown_track_is_404(client: Client) -> None:
    assert (
        client.get("/tracks/no_such_track/race.png", {"race_type": "HEAD_TO_BOT"}).status_code
        == 404
    )


def test_the_tracks_page_shows_the_layout_asked_for(client: Client) -> None:
    html = client.get("/tracks/").content.decode()
    assert 'id="layout-form"' in html and 'id="layout-preview"' not in html
    response = client.get("/tracks/", {"track": "racecraft_oval", "race_type": "HEAD_TO_BOT",
                                       "number_of_bots": "3"})  # fmt: skip
    assert response.status_code == 200
    html = response.content.decode()
    src = f"{URL}?race_type=HEAD_TO_BOT&amp;number_of_bots=3"
    assert f'src="{src}"' in html
    image = client.get(src.replace("&amp;", "&"))
    assert image.status_code == 200 and patches(image.content, BOT_RGB) == 3


def test_the_tracks_page_puts_a_refused_setting_on_its_field(client: Client) -> None:
    response = client.get("/tracks/", {"track": "racecraft_oval", "race_type": "OBJECT_AVOIDANCE",
                                       "object_positions": "0.5,3"})  # fmt: skip
    assert response.status_code == 400
    html = response.content.decode()
    assert 'id="layout-preview"' not in html
    assert 'id="field-object_positions"' in html and "has-error" in html
    assert "A lane is 1 (inner) or -1 (outer), not 3" in html
    assert 'value="0.5,3"' in html  # nothing typed is lost


def test_objects_that_do_not_fit_the_track_are_refused_in_words() -> None:
    race = {"number_of_objects": 6, "min_object_gap_m": 9.0}
    with pytest.raises(ValueError, match="do not fit"):
        tracks.race_preview("racecraft_oval", "native", "OBJECT_AVOIDANCE", race)


def test_an_address_asking_for_too_many_pictures_gets_a_429(client: Client, settings) -> None:
    from tests.conftest import clear_cache

    settings.RACECRAFT_PREVIEW_RATE = "2/m"
    clear_cache()
    try:
        query = {"race_type": "HEAD_TO_BOT"}
        assert [client.get(URL, query).status_code for _ in range(2)] == [200, 200]
        refused = client.get(URL, query)
        assert refused.status_code == 429
        assert "Too many layout previews" in refused.content.decode()
        page = client.get("/tracks/", {"track": "racecraft_oval", **query})
        assert page.status_code == 400 and "Too many layout previews" in page.content.decode()
    finally:
        clear_cache()
