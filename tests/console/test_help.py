"""/help/: the guides in docs/ rendered in the console, for anyone who can reach it.

A self-hosted install's racers find help without the repository: every guide renders with its
headings anchored (``/help/racer/#training``), links between guides stay inside /help/, raw
HTML in a guide is shown as text, and the pages need nothing the Content Security Policy
forbids. The console's "?" links land on headings that exist.
"""

from __future__ import annotations

import os
import re
import time
from pathlib import Path

import pytest
from django.conf import settings
from django.test import Client

from console import helpdocs
from tests.console.conftest import make_model

ROOT = Path(__file__).resolve().parents[2]


def _ids(html: str) -> set[str]:
    return set(re.findall(r'<h[1-6] id="([^"]+)"', html))


def test_the_help_index_lists_every_guide_for_anyone(client: Client) -> None:
    response = client.get("/help/")
    assert response.status_code == 200
    html = response.content.decode()
    for guide in helpdocs.GUIDES:
        assert f'href="/help/{guide.slug}/"' in html
        assert guide.title.replace("'", "&#x27;") in html


@pytest.mark.parametrize("guide", helpdocs.GUIDES, ids=lambda g: g.slug)
def test_each_guide_renders_with_its_headings_anchored(client: Client, guide) -> None:
    response = client.get(f"/help/{guide.slug}/")
    assert response.status_code == 200
    html = response.content.decode()
    rendered = helpdocs.guide_render(guide.slug)
    assert rendered.title == guide.title
    ids = _ids(html)
    source = (ROOT / "docs" / guide.filename).read_text(encoding="utf-8")
    headings = [line for line in source.splitlines() if re.match(r"#{1,3} ", line)]
    assert headings, "a guide has headings"
    # Every heading of the file (outside code blocks, which the fences below strip) has an id,
    # and the contents list links each section.
    assert len(ids) >= len(rendered.headings) + 1
    for heading in rendered.headings:
        assert heading.anchor in ids
        assert f'href="#{heading.anchor}"' in html
    assert f'id="{helpdocs.heading_anchor(guide.title)}"' in html
    assert 'href="/help/"' in html  # the nav's Help link and the breadcrumb


def test_a_logged_in_racer_sees_the_same_guide(alice_client: Client) -> None:
    response = alice_client.get("/help/racer/")
    assert response.status_code == 200
    html = response.content.decode()
    for section in ("models", "rewards", "training", "evaluation", "imports-and-exports",
                    "the-car", "logs-and-analysis"):  # fmt: skip
        assert f'id="{section}"' in html
    assert 'aria-current="page">Help</a>' in html


def test_links_between_guides_stay_in_help(client: Client) -> None:
    html = client.get("/help/racer/").content.decode()
    assert 'href="/help/organiser/#head-to-head-racing-and-race-days"' in html
    assert 'href="/help/security/"' in html
    assert ".md" not in "".join(re.findall(r'href="([^"]+)"', html))
    organiser = client.get("/help/organiser/").content.decode()
    picture = re.search(r"<article.*?<img src=\"([^\"]+)\"", organiser, re.S)
    assert picture and picture[1] == "/static/img/broadcast.jpg"
    assert (ROOT / "static" / "img" / "broadcast.jpg").is_file()


def test_an_unknown_guide_is_404(client: Client) -> None:
    assert client.get("/help/no-such-guide/").status_code == 404


def test_the_pages_pass_the_content_security_policy(client: Client) -> None:
    response = client.get("/help/operator/")
    policy = response["Content-Security-Policy"]
    assert "script-src 'self'" in policy
    html = response.content.decode()
    article = html.split('<article class="help-doc">', 1)[1].split("</article>", 1)[0]
    assert "<script" not in article
    assert "style=" not in article  # table alignment would write inline styles
    assert not re.search(r"<script(?![^>]*\bsrc=)[^>]*>", html)  # no inline script on the page
    assert not re.search(r"\son[a-z]+=", html)  # no inline event handlers


@pytest.fixture
def docs_dir(tmp_path, settings):
    settings.BASE_DIR = tmp_path
    (tmp_path / "docs").mkdir()
    helpdocs._render.cache_clear()
    yield tmp_path / "docs"
    helpdocs._render.cache_clear()


def test_raw_html_and_script_links_in_a_guide_are_shown_as_text(client, docs_dir) -> None:
    (docs_dir / "racer.md").write_text(
        "# The racer's guide\n\n## Safe\n\n<script>alert(1)</script>\n\n"
        '<img src=x onerror="alert(2)">\n\n[click](javascript:alert(3))\n\n'
        "| a | b |\n|--:|:-:|\n| 1 | 2 |\n",
        encoding="utf-8",
    )
    response = client.get("/help/racer/")
    assert response.status_code == 200
    html = response.content.decode()
    assert "<script>alert(1)" not in html
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in html
    assert "<img src=x" not in html and 'onerror="alert' not in html
    assert 'href="javascript:' not in html
    assert "<table>" in html and "style=" not in html  # aligned columns, no inline style


def test_an_edited_guide_renders_again(client, docs_dir) -> None:
    path = docs_dir / "organiser.md"
    path.write_text("# The organiser's guide\n\n## Before\n", encoding="utf-8")
    assert 'id="before"' in client.get("/help/organiser/").content.decode()
    path.write_text("# The organiser's guide\n\n## After\n", encoding="utf-8")
    later = time.time() + 5  # a coarse file system clock must see a change
    os.utime(path, (later, later))
    assert 'id="after"' in client.get("/help/organiser/").content.decode()


def test_a_checkout_without_its_guides_says_so_without_a_path(client, docs_dir) -> None:
    response = client.get("/help/operator/")
    assert response.status_code == 404
    assert str(docs_dir) not in response.content.decode()


def test_headings_are_anchored_as_github_anchors_them() -> None:
    assert helpdocs.heading_anchor("Where a policy update's time goes") == (
        "where-a-policy-updates-time-goes"
    )
    assert helpdocs.heading_anchor("bench_training, change by change") == (
        "bench_training-change-by-change"
    )
    assert helpdocs.heading_anchor("Head-to-head racing and race days") == (
        "head-to-head-racing-and-race-days"
    )
    assert helpdocs.guide_link_target("operator.md#backups") == "/help/operator/#backups"
    assert helpdocs.guide_link_target("../README.md") is None
    assert helpdocs.guide_link_target("https://example.com/racer.md") is None


# --- the console's "?" links ----------------------------------------------------------------

HELP_LINK = re.compile(r'help/_link\.html" with guide="(\w+)" section="([\w-]+)"')


def _help_links() -> list[tuple[str, str, str]]:
    found = []
    for path in sorted((ROOT / "templates").rglob("*.html")):
        for guide, section in HELP_LINK.findall(path.read_text(encoding="utf-8")):
            found.append((str(path.relative_to(ROOT)), guide, section))
    return found


def test_every_help_link_in_the_templates_lands_on_a_heading() -> None:
    links = _help_links()
    assert len(links) >= 6
    wrong = [
        (template, f"/help/{guide}/#{section}")
        for template, guide, section in links
        if section not in {h.anchor for h in helpdocs.guide_render(guide).headings}
    ]
    assert wrong == []


def test_the_model_pages_link_their_help(alice_client: Client, alice, store_dir) -> None:
    html = alice_client.get("/models/new/").content.decode()
    assert 'href="/help/racer/#models"' in html
    assert 'href="/help/racer/#rewards"' in html
    model = make_model(alice)
    assert (
        'href="/help/racer/#training"' in alice_client.get(f"/models/{model.pk}/").content.decode()
    )
    assert (
        'href="/help/racer/#imports-and-exports"'
        in alice_client.get("/models/import/").content.decode()
    )


def test_the_league_links_the_organiser_s_guide(alice_client: Client) -> None:
    html = alice_client.get("/league/").content.decode()
    assert 'href="/help/organiser/#league"' in html
    assert settings.STATIC_URL in html  # the page itself rendered, not an error page
