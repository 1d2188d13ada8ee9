"""Browser code installed from the npm registry at set-up time and bundled with esbuild.

The CodeMirror editor (assets/codemirror.js + the packages pinned in package.json and
package-lock.json) becomes static/vendor/codemirror.bundle.js, and the charts of the model
pages (assets/charts.js: Chart.js) static/vendor/charts.bundle.js; both are git-ignored: a
fresh clone builds them on the first ``manage.py up`` (or ``manage.py build_assets``).
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

from django.conf import settings

BUNDLES = ("vendor/codemirror.bundle.js", "vendor/charts.bundle.js")
"""The bundles' paths under static/."""


class AssetBuildError(RuntimeError):
    """npm or esbuild failed, or node is missing; the message says which."""


def bundle_paths() -> list[Path]:
    return [Path(settings.BASE_DIR) / "static" / bundle for bundle in BUNDLES]


def sources() -> list[Path]:
    base = Path(settings.BASE_DIR)
    return [
        base / "package.json",
        base / "package-lock.json",
        *sorted((base / "assets").glob("*.js")),
    ]


def bundle_is_fresh() -> bool:
    """Every bundle exists and is newer than every source it is built from."""
    bundles = bundle_paths()
    if not all(bundle.exists() for bundle in bundles):
        return False
    built = min(bundle.stat().st_mtime for bundle in bundles)
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
    missing = [str(bundle) for bundle in bundle_paths() if not bundle.exists()]
    if missing:
        raise AssetBuildError(f"the build ran but {', '.join(missing)} is missing")
    return True
