"""Where the tests find the repository's files, wherever in ``tests/`` a test module sits."""

from pathlib import Path

#: The repository's root (configs/, notebooks/, scripts/).
REPO = Path(__file__).resolve().parents[2]
#: The tiny run's config (one concept, 6 frames of 32x32, a small model).
TINY_CONFIG = str(REPO / "tests" / "configs" / "tiny.yaml")
