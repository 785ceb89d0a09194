"""Where the repository's assets live."""

from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[2]
ASSETS = REPO_ROOT / "assets"
SCENES = ASSETS / "scenes"
