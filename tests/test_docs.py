"""The README and the guides in docs/ say only what the code does: a doc that drifts fails here.

Each guide names commands, options, settings, URLs, files and modules. Every one of them is
checked against the code: a ``manage.py`` command and each ``--option`` written with it exist;
a ``RACECRAFT_*`` name is read somewhere; every variable that settings read is in the
operator's Configuration table; a URL resolves; a path exists; a dotted module name imports;
a link between guides lands on a heading that exists. The README stays a front page.
"""

from __future__ import annotations

import importlib
import re
from functools import cache
from pathlib import Path

import pytest
from django.conf import settings
from django.core.management import get_commands, load_command_class
from django.urls import Resolver404, resolve

from console import helpdocs

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
README = ROOT / "README.md"
PACKAGES = ("racing", "training", "leaderboard", "console")
# Built by `manage.py build_assets` (git-ignored): named, never committed.
GENERATED = {"static/vendor/codemirror.bundle.js"}

CODE_SPAN = re.compile(r"(?<!`)`([^`]+)`(?!`)")
FENCE = re.compile(r"^```[^\n]*\n(.*?)^```", re.M | re.S)


def _docs() -> list[Path]:
    return sorted(DOCS.glob("*.md"))


def _all_docs() -> list[Path]:
    return [README, *_docs()]


def _text(path: Path) -> str:
    return path.read_text(encoding="utf-8")


def _snippets(text: str) -> list[str]:
    """Code spans (wrapped lines joined) and fenced blocks' lines (`\\` continuations joined)."""
    out = [" ".join(span.split()) for span in CODE_SPAN.findall(FENCE.sub("", text))]
    for block in FENCE.findall(text):
        out.extend(line.strip() for line in block.replace("\\\n", " ").splitlines())
    return [s for s in out if s]


@cache
def _code_text() -> str:
    """Every Python file of ours (packages, benchmarks, tests but this one) in one string."""
    files = [p for pkg in (*PACKAGES, "bench", "tests") for p in (ROOT / pkg).rglob("*.py")]
    files.remove(Path(__file__).resolve())  # the names this file quotes prove nothing
    return "\n".join(p.read_text(encoding="utf-8", errors="replace") for p in files)


def _ids(paths: list[Path]) -> list[str]:
    return [p.name for p in paths]


# --- the set of guides ----------------------------------------------------------------------


def test_every_guide_file_is_served_and_every_served_guide_exists():
    on_disk = {p.name for p in _docs()}
    served = {g.filename for g in helpdocs.GUIDES}
    assert on_disk == served, "docs/*.md and console/helpdocs.GUIDES must list the same guides"


@pytest.mark.parametrize("guide", helpdocs.GUIDES, ids=lambda g: g.slug)
def test_each_guide_opens_with_its_title(guide):
    first = _text(DOCS / guide.filename).splitlines()[0]
    assert first == f"# {guide.title}"


# --- the README: the front page -------------------------------------------------------------


def test_readme_is_a_front_page_that_starts_with_the_two_commands():
    text = _text(README)
    lines = text.splitlines()
    assert len(lines) <= 250, f"README.md has {len(lines)} lines; the guides go in docs/"
    assert lines[2] == "Start the console (then open http://127.0.0.1:8000):"
    assert lines[5] == (
        "python3 -m venv .venv && .venv/bin/pip install -e '.[dev]' && "
        ".venv/bin/python manage.py up"
    )
    assert lines[8] == "Run the tests:"
    assert lines[11] == (
        "python3 -m venv .venv && .venv/bin/pip install -e '.[dev]' && .venv/bin/pytest"
    )
    assert "## Licence" in text
    assert "](static/img/" in text, "the front page shows a screenshot"
    for guide in helpdocs.GUIDES:
        assert f"](docs/{guide.filename}" in text, f"the README links {guide.filename}"


# --- links between the README and the guides land on headings -------------------------------

LINK = re.compile(r"\]\(([^)\s]+)\)")


@cache
def _anchors(path: Path) -> set[str]:
    anchors: set[str] = set()
    counts: dict[str, int] = {}
    for line in FENCE.sub("", _text(path)).splitlines():
        if match := re.match(r"#{1,6} (.+)", line):
            base = helpdocs.heading_anchor(CODE_SPAN.sub(r"\1", match[1]))
            n = counts.get(base, 0)
            counts[base] = n + 1
            anchors.add(base if n == 0 else f"{base}-{n}")
    return anchors


@pytest.mark.parametrize("doc", _all_docs(), ids=_ids(_all_docs()))
def test_every_relative_link_lands_on_a_file_and_heading(doc):
    broken = []
    for href in LINK.findall(_text(doc)):
        if re.match(r"[a-z]+:", href):  # http:, https:, mailto:
            continue
        target, _, anchor = href.partition("#")
        path = (doc.parent / target).resolve() if target else doc
        lands = path.exists() and (
            not anchor or (path.suffix == ".md" and anchor in _anchors(path))
        )
        if not lands:
            broken.append(href)
        elif doc != README and target.startswith("../static/"):
            continue  # a picture, served from /static/ (console/helpdocs.py)
        elif doc != README and target and not helpdocs.guide_link_target(href):
            broken.append(f"{href} (not a guide: /help/ cannot follow it)")
    assert not broken


# --- commands and their options -------------------------------------------------------------

MANAGE = re.compile(r"manage\.py (\w+)(.*)")
RACECRAFT_COMMAND = re.compile(r"^(racecraft_\w+)( .*)?$")
OPTION = re.compile(r"(?<![\w-])(--[a-z][a-z0-9-]*)")


@cache
def _command_options(name: str) -> set[str]:
    command = load_command_class(get_commands()[name], name)
    parser = command.create_parser("manage.py", name)
    return set(parser._option_string_actions)


def _invocations(text: str) -> list[tuple[str, str]]:
    """(command, its arguments) for each `manage.py X ...` and each span `racecraft_X ...`."""
    found = []
    for snippet in _snippets(text):
        for match in MANAGE.finditer(snippet):
            found.append((match[1], match[2].split("&&")[0]))
        if match := RACECRAFT_COMMAND.match(snippet):
            found.append((match[1], match[2] or ""))
    return found


@pytest.mark.parametrize("doc", _all_docs(), ids=_ids(_all_docs()))
def test_every_command_named_exists_with_the_options_written(doc):
    commands = get_commands()
    wrong = []
    for name, args in _invocations(_text(doc)):
        if name == "help":  # `manage.py help` lists the commands
            continue
        if name not in commands:
            if name.startswith("racecraft_") and f'"{name}"' in _code_text():
                continue  # a track id or a metadata key, not a command
            wrong.append(f"manage.py {name}: no such command")
            continue
        for option in OPTION.findall(args):
            if option not in _command_options(name):
                wrong.append(f"manage.py {name} {option}: no such option")
    assert not wrong


def test_the_guides_name_the_commands_a_racer_and_an_operator_use():
    """The checks above see these invocations (a pattern that stopped matching passes nothing)."""
    named = {name for doc in _all_docs() for name, _ in _invocations(_text(doc))}
    assert {"up", "migrate", "check", "import_track", "build_assets", "promote_divisions"} <= named
    assert {"racecraft_create_model", "racecraft_evaluate", "racecraft_race"} <= named
    assert {"racecraft_import"} <= named


BENCH = re.compile(r"(bench/\w+\.py)(.*)")
MODULE_RUN = re.compile(r"python -m ((?:racing|training|leaderboard|console)[\w.]*)(.*)")


@pytest.mark.parametrize("doc", _all_docs(), ids=_ids(_all_docs()))
def test_every_script_named_exists_and_takes_the_options_written(doc):
    wrong = []
    for snippet in _snippets(_text(doc)):
        runs = [(ROOT / m[1], m[2]) for m in BENCH.finditer(snippet)]
        runs += [
            (ROOT / (m[1].replace(".", "/") + ".py"), m[2]) for m in MODULE_RUN.finditer(snippet)
        ]
        for path, args in runs:
            if not path.exists():
                wrong.append(f"{path.relative_to(ROOT)}: no such file")
                continue
            source = path.read_text(encoding="utf-8")
            for option in OPTION.findall(args):
                if f'"{option}"' not in source:
                    wrong.append(f"{path.relative_to(ROOT)} {option}: no such option")
    assert not wrong


def test_every_benchmark_is_in_the_benchmarks_guide():
    text = _text(DOCS / "benchmarks.md")
    missing = [p.name for p in sorted((ROOT / "bench").glob("bench_*.py")) if p.name not in text]
    assert not missing


# --- settings -------------------------------------------------------------------------------

SETTING = re.compile(r"\bRACECRAFT_[A-Z0-9_]*[A-Z0-9]\b")
READ = re.compile(r"""env\w*\(\s*["']([A-Z][A-Z0-9_]+)["']""")


@pytest.mark.parametrize("doc", _all_docs(), ids=_ids(_all_docs()))
def test_every_racecraft_setting_named_is_read_by_the_code(doc):
    code = _code_text()
    unread = sorted(
        {
            name
            for name in SETTING.findall(_text(doc))
            if f'"{name}"' not in code and f"'{name}'" not in code
        }
    )
    assert not unread


def _configuration_table() -> set[str]:
    section = _text(DOCS / "operator.md").split("## Configuration", 1)[1].split("\n## ", 1)[0]
    return {
        name
        for row in section.splitlines()
        if row.startswith("| `")
        for name in re.findall(r"`([A-Z][A-Z0-9_]+)`", row)
    }


def test_every_variable_the_settings_read_is_in_the_configuration_table():
    read = set()
    for path in (ROOT / "console").glob("*.py"):
        read |= set(READ.findall(path.read_text(encoding="utf-8")))
    assert {"DEBUG", "SECRET_KEY", "RACECRAFT_TORCH_DEVICE"} <= read  # the pattern still matches
    documented = _configuration_table()
    assert sorted(read - documented) == [], "add a row to docs/operator.md's Configuration"
    first_column = {
        name
        for name in documented
        if re.search(rf"^\| `{name}`|^\| `[A-Z_]+`, `{name}`", _text(DOCS / "operator.md"), re.M)
    }
    # A row's own variable is read by the settings (OMP_WAIT_POLICY: by the launcher).
    assert sorted(first_column - read - {"OMP_WAIT_POLICY"}) == []


# --- URLs -----------------------------------------------------------------------------------

URL = re.compile(r"^(/[A-Za-z0-9_./<>-]*)(?:[?#]\S*)?$")
NOT_URLS = ("/usr/", "/proc", "/path/", "/tmp/", "/dev", "/etc/", "/sys/")


def _urls(text: str) -> set[str]:
    return {
        m[1]
        for snippet in _snippets(text)
        if (m := URL.match(snippet)) and not m[1].startswith(NOT_URLS)
    }


def _resolves(url: str) -> bool:
    if url.startswith(settings.STATIC_URL):  # served by the web server, not the URLconf
        return True
    # A placeholder (`<id>`, `<chart>`, `<token>`) stands for a number or a word.
    for value in ("1", "reward"):
        try:
            resolve(re.sub(r"<[^>]+>", value, url))
        except Resolver404:
            continue
        return True
    return False


@pytest.mark.parametrize("doc", _all_docs(), ids=_ids(_all_docs()))
def test_every_url_named_resolves(doc):
    assert [url for url in sorted(_urls(_text(doc))) if not _resolves(url)] == []


def test_the_guides_name_urls_that_the_check_sees():
    named = set().union(*(_urls(_text(doc)) for doc in _all_docs()))
    assert {"/help/", "/league/events/new/", "/models/<id>/analysis/", "/admin/"} <= named


def test_the_url_check_catches_a_stale_url():
    assert _resolves("/models/<id>/analysis/")
    assert not _resolves("/models/<id>/analytics/")


# --- files and modules ----------------------------------------------------------------------

PATH = re.compile(
    r"(?<![\w./-])((?:racing|training|leaderboard|console|tests|bench|templates|static|assets"
    r"|docs|\.ci)/[A-Za-z0-9_./*-]*)"
)
TEST_FILE = re.compile(r"(?<![\w/*-])(test_[A-Za-z0-9_*]+\.py)\b")
MODULE = re.compile(r"^((?:racing|training|leaderboard|console)(?:\.\w+)+)(?::(\w+))?$")


def _paths(text: str) -> set[str]:
    return {m.rstrip(".") for m in PATH.findall(text)}


@pytest.mark.parametrize("doc", _all_docs(), ids=_ids(_all_docs()))
def test_every_file_named_exists(doc):
    text = _text(doc)
    missing = []
    for name in sorted(_paths(text) - GENERATED):
        if not list(ROOT.glob(name.rstrip("/"))):
            missing.append(name)
    tests = ROOT / "tests"
    for name in sorted(set(TEST_FILE.findall(text))):
        if not list(tests.rglob(name)):
            missing.append(name)
    assert not missing


def _importable(dotted: str, attribute: str | None) -> bool:
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ModuleNotFoundError:
            continue
        try:
            for name in [*parts[cut:], *([attribute] if attribute else [])]:
                obj = getattr(obj, name)
        except AttributeError:
            return False
        return True
    return False


@pytest.mark.parametrize("doc", _all_docs(), ids=_ids(_all_docs()))
def test_every_module_and_name_named_imports(doc):
    named = {(m[1], m[2]) for snippet in _snippets(_text(doc)) if (m := MODULE.match(snippet))}
    assert [f"{d}:{a}" if a else d for d, a in sorted(named) if not _importable(d, a)] == []


def test_the_checks_catch_a_stale_command_option_module_and_setting():
    stale = (
        "`manage.py racecraft_train 3 --no-such-flag`, `racecraft_frobnicate --x`, "
        "`training.services.no_such_thing`, RACECRAFT_NO_SUCH_SETTING"
    )
    invocations = _invocations(stale)
    assert invocations == [
        ("racecraft_train", " 3 --no-such-flag"),
        ("racecraft_frobnicate", " --x"),
    ]
    assert "--no-such-flag" not in _command_options("racecraft_train")
    assert "racecraft_frobnicate" not in get_commands()
    assert not _importable("training.services.no_such_thing", None)
    assert _importable("training.models", "TrackFile")
    assert '"RACECRAFT_NO_SUCH_SETTING"' not in _code_text()


def test_the_file_check_catches_a_stale_path():
    assert _paths("see `training/rl/presets.py` and training/rl/no_such_file.py.") == {
        "training/rl/presets.py",
        "training/rl/no_such_file.py",
    }
    assert not list(ROOT.glob("training/rl/no_such_file.py"))


# --- the code's references to the guides -------------------------------------------------------

CITATION = re.compile(r'(docs/\w+\.md|README),\s+"([^"]+)"')


def test_every_section_the_code_cites_is_in_its_guide():
    """A docstring that says (docs/benchmarks.md, "Faster laps") names a heading or a bold
    paragraph lead of that guide; (README, "...") a section the front page still has."""
    citations = {(m[1], " ".join(m[2].split())) for m in CITATION.finditer(_code_text())}
    assert ("docs/benchmarks.md", "Faster laps") in citations
    missing = []
    for doc, title in sorted(citations):
        text = " ".join(_text(ROOT / ("README.md" if doc == "README" else doc)).split())
        if f"**{title}" not in text and f"# {title}" not in text:
            missing.append(f'{doc}, "{title}"')
    assert missing == []


# --- stale facts the issue named ------------------------------------------------------------


def test_the_racing_preset_top_speed_is_the_code_s():
    from training.catalog import preset

    top = max(a["speed"] for a in preset("racing").action_space)
    assert f"(up to {top:g} m/s" in _text(DOCS / "racer.md")
    assert f"up to {top:g} m/s" in _text(README)
