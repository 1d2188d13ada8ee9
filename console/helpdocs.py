"""The guides in ``docs/``, rendered for the console's help pages (``/help/``).

One list of guides (``GUIDES``: slug, file, what it is for); each renders from its Markdown
file under ``settings.BASE_DIR / "docs"``, where the templates and static files live too, so a
checkout run in place (``pip install -e .``) and a fresh clone read the same files.

Rendering is markdown-it-py's CommonMark with tables, raw HTML off (any ``<tag>`` in a guide is
shown as text, never passed through), and three changes to the tokens:

- every heading gets an ``id`` as GitHub makes it (``"Where a policy update's time goes"`` →
  ``where-a-policy-updates-time-goes``), so ``/help/racer/#training`` and
  ``docs/racer.md#training`` on GitHub name the same section;
- a link to another guide (``operator.md#backups``) becomes its help page
  (``/help/operator/#backups``), so the guides link to each other in the console, and a
  picture from ``static/`` (``../static/img/broadcast.jpg``) is served from ``/static/``;
- no ``style`` attribute is written (table alignment), so the page needs no inline style.
"""

from __future__ import annotations

import re
import unicodedata
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from django.conf import settings
from django.templatetags.static import static
from django.urls import reverse
from markdown_it import MarkdownIt
from markdown_it.rules_core import StateCore
from markdown_it.token import Token


@dataclass(frozen=True)
class Guide:
    slug: str
    filename: str
    title: str  # the file's first heading (tests/test_docs.py holds them equal)
    summary: str


GUIDES: tuple[Guide, ...] = (
    Guide(
        "racer",
        "racer.md",
        "The racer's guide",
        "Models, rewards, training, evaluation, the car, imports and exports, logs and analysis.",
    ),
    Guide(
        "organiser",
        "organiser.md",
        "The organiser's guide",
        "The league, events, divisions, head-to-head brackets and race days.",
    ),
    Guide(
        "operator",
        "operator.md",
        "The operator's guide",
        "Settings, production, several machines, backups, upgrades and reliability.",
    ),
    Guide(
        "security",
        "security.md",
        "Security",
        "The sandbox's layers, what each stops and where it is tested.",
    ),
    Guide(
        "compatibility",
        "compatibility.md",
        "DeepRacer compatibility",
        "Every DeepRacer format, what reads it and how it is tested.",
    ),
    Guide(
        "architecture",
        "architecture.md",
        "Architecture",
        "How it works, the packages, and where to make a change.",
    ),
    Guide(
        "benchmarks",
        "benchmarks.md",
        "Benchmarks",
        "Every benchmark, its command and its measured history.",
    ),
)
GUIDES_BY_SLUG = {g.slug: g for g in GUIDES}
_SLUG_BY_FILE = {g.filename: g.slug for g in GUIDES}


class UnknownGuide(LookupError):
    """No guide has this slug."""


@dataclass(frozen=True)
class Heading:
    level: int
    anchor: str
    text: str


@dataclass(frozen=True)
class RenderedGuide:
    guide: Guide
    title: str
    html: str
    headings: tuple[Heading, ...]  # level 2 and 3, in order: the page's contents


def docs_dir() -> Path:
    return Path(settings.BASE_DIR) / "docs"


def guide_path(guide: Guide) -> Path:
    return docs_dir() / guide.filename


def heading_anchor(text: str) -> str:
    """GitHub's heading id: lower case, punctuation dropped, each space a hyphen."""
    out = []
    for ch in text.strip().lower():
        if ch in " -":
            out.append("-")
        elif ch == "_" or unicodedata.category(ch)[0] in "LN":
            out.append(ch)
    return "".join(out)


def _inline_text(token: Token) -> str:
    return "".join(child.content for child in token.children or () if child.content)


_STATIC_PREFIX = "../static/"
_GUIDE_LINK = re.compile(r"^(?:\./)?(?P<file>[A-Za-z0-9_-]+\.md)(?:#(?P<anchor>[^\s]*))?$")


def guide_link_target(href: str) -> str | None:
    """The help page a guide's relative link (``operator.md#backups``) stands for, else None."""
    match = _GUIDE_LINK.match(href)
    if not match or match["file"] not in _SLUG_BY_FILE:
        return None
    url = reverse("help-guide", args=[_SLUG_BY_FILE[match["file"]]])
    return f"{url}#{match['anchor']}" if match["anchor"] else url


def _anchor_headings(state: StateCore) -> None:
    seen: dict[str, int] = {}
    headings: list[Heading] = []
    tokens = state.tokens
    for i, token in enumerate(tokens):
        if token.type == "heading_open":
            text = _inline_text(tokens[i + 1])
            base = heading_anchor(text)
            count = seen.get(base, 0)
            seen[base] = count + 1
            anchor = base if count == 0 else f"{base}-{count}"
            token.attrSet("id", anchor)
            headings.append(Heading(int(token.tag[1]), anchor, text))
    state.env["headings"] = headings


def _rewrite_links(state: StateCore) -> None:
    for token in state.tokens:
        for child in token.children or ():
            if child.type == "link_open":
                target = guide_link_target(str(child.attrGet("href") or ""))
                if target:
                    child.attrSet("href", target)
            elif child.type == "image":
                # A picture of the console, ../static/img/x.jpg from docs/: served as static.
                src = str(child.attrGet("src") or "")
                if src.startswith(_STATIC_PREFIX):
                    child.attrSet("src", static(src.removeprefix(_STATIC_PREFIX)))


def _drop_styles(state: StateCore) -> None:
    for token in state.tokens:
        if token.attrs and "style" in token.attrs:
            del token.attrs["style"]


def _parser() -> MarkdownIt:
    md = MarkdownIt("commonmark", {"html": False}).enable("table")
    md.core.ruler.push("racecraft_heading_anchors", _anchor_headings)
    md.core.ruler.push("racecraft_guide_links", _rewrite_links)
    md.core.ruler.push("racecraft_no_styles", _drop_styles)
    return md


def guide_render(slug: str) -> RenderedGuide:
    """The guide ``slug`` rendered to HTML; raises UnknownGuide, or OSError if its file is gone."""
    guide = GUIDES_BY_SLUG.get(slug)
    if guide is None:
        raise UnknownGuide(slug)
    path = guide_path(guide)
    return _render(guide, str(path), path.stat().st_mtime_ns)


@lru_cache(maxsize=16)
def _render(guide: Guide, path: str, mtime_ns: int) -> RenderedGuide:
    # Keyed on the file's modification time: an edited guide renders again, an unchanged one once.
    source = Path(path).read_text(encoding="utf-8")
    env: dict = {}
    html = _parser().render(source, env)
    headings: list[Heading] = env.get("headings", [])
    title = next((h.text for h in headings if h.level == 1), guide.title)
    contents = tuple(h for h in headings if h.level in (2, 3))
    return RenderedGuide(guide=guide, title=title, html=html, headings=contents)
