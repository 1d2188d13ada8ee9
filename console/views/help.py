"""The help pages: the guides in docs/, rendered (console/helpdocs.py), open to everyone."""

from __future__ import annotations

from django.http import Http404, HttpRequest, HttpResponse
from django.shortcuts import render
from django.utils.safestring import mark_safe
from django.views.decorators.http import require_safe

from console import helpdocs


@require_safe
def help_index(request: HttpRequest) -> HttpResponse:
    return render(request, "help/index.html", {"nav": "help", "guides": helpdocs.GUIDES})


@require_safe
def help_guide(request: HttpRequest, slug: str) -> HttpResponse:
    try:
        guide = helpdocs.guide_render(slug)
    except helpdocs.UnknownGuide:
        raise Http404("No such guide.") from None
    except OSError:
        # A checkout without its docs/ folder: say so, never the path.
        raise Http404("This guide is not installed.") from None
    return render(
        request,
        "help/guide.html",
        {
            "nav": "help",
            "guide": guide,
            # Rendered with raw HTML off: markdown-it escapes any tag a guide holds.
            "body": mark_safe(guide.html),
            "guides": helpdocs.GUIDES,
        },
    )
