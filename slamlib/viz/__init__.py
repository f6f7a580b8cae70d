"""Plotting for the book: the only part of slamlib that imports matplotlib.

Functions live in private submodules by topic (``_core``: poses, ellipses,
particles, landmarks, grids, animations; ``_localization``; ``_slam``) and are
re-exported here. Every function takes an optional ``ax`` and returns it.
"""

from ._core import *  # noqa: F401,F403
