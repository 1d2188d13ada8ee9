"""Browser code installed from the npm registry at set-up time and bundled with esbuild.

The CodeMirror editor (assets/codemirror.js + the packages pinned in package.json and
package-lock.json) becomes static/vendor/codemirror.bundle.js, which is git-ignored: a fresh
clone builds it on the first ``manage.py up`` (or ``manage.py build_assets``).
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

from django.conf import settings

BUNDLE = "vendor/codemirror.bundle.js"
"""The bundle's path under static/."""


class AssetBuildError(RuntimeError):
    """npm or esbuild failed, or node is missing; the message says which."""


def bundle_path() -> Path:
    return Path(settings.BASE_DIR) / "static" / BUNDLE


def sources() -> list[Path]:
    base = Path(settings.BASE_DIR)
    return [
        base / "package.json",
        base / "package-lock.json",
        *sorted((base / "assets").glob("*.js")),
    ]


def bundle_is_fresh() -> bool:
    """The bundle exists and is newer than every source it is built from."""
    bundle = bundle_path()
    if not bundle.exists():
        return False
    built = bundle.stat().st_mtime
    return all(not src.exists() or src.stat().st_mtime <= built for src in sources())


def _run(argv: list[str], cwd: Path) -> None:
    try:
        done = subprocess.run(argv, cwd=cwd, capture_output=True, text=True, timeout=600)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise AssetBuildError(f"{' '.join(argv)} failed: {exc}") from None
    if done.returncode != 0:
        raise AssetBuildError(
            f"{' '.join(argv)} failed:\n{done.stdout[-2000:]}{done.stderr[-2000:]}"
        )


def build_assets(*, force: bool = False) -> bool:
    """Install the npm packages (``npm ci``) when needed and bundle the editor.

    Returns True when something was built, False when the bundle was already fresh.
    Raises AssetBuildError when node/npm are missing or a step fails.
    """
    if not force and bundle_is_fresh():
        return False
    base = Path(settings.BASE_DIR)
    npm = shutil.which("npm")
    if npm is None:
        raise AssetBuildError("npm is not installed: install Node.js (18 or newer) and npm")
    esbuild = base / "node_modules" / ".bin" / "esbuild"
    lock = base / "package-lock.json"
    if (
        force
        or not esbuild.exists()
        or (lock.exists() and lock.stat().st_mtime > esbuild.stat().st_mtime)
    ):
        _run([npm, "ci", "--no-audit", "--no-fund"], base)
    _run([npm, "run", "--silent", "build"], base)
    if not bundle_path().exists():
        raise AssetBuildError(f"the build ran but {bundle_path()} is missing")
    return True
