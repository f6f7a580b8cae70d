"""Plotting for the book: the only part of slamlib that imports matplotlib.

Functions live in private submodules by topic (``_core``: poses, ellipses,
particles, landmarks, grids, animations; ``_bayes``; ``_filters``; ``_mcl``;
``_slam``; ``_fastslam``; ``_real_data``; ``_graph``; ``_graph3d``; ``_scan``) and are
re-exported here. Every function takes an optional ``ax`` and returns it.
"""

from ._core import *  # noqa: F401,F403
from ._bayes import *  # noqa: F401,F403
from ._filters import *  # noqa: F401,F403
from ._mcl import *  # noqa: F401,F403
from ._slam import *  # noqa: F401,F403
from ._fastslam import *  # noqa: F401,F403
from ._real_data import *  # noqa: F401,F403
from ._graph import *  # noqa: F401,F403
from ._scan import *  # noqa: F401,F403
from ._victoria import *  # noqa: F401,F403
from ._graph3d import *  # noqa: F401,F403
from ._camera import *  # noqa: F401,F403
from ._describe import describe_figure  # noqa: F401
from ._describe import install as _install_figure_alt

_install_figure_alt()  # in an IPython kernel: every figure's image output carries describe_figure(fig) as alt
