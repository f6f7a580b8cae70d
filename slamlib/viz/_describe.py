"""Text alternatives of figures: every static figure of the book says in words what it shows.

`describe_figure` reads a figure's own content (suptitle, each panel's title, axis labels,
legend entries, colour-scale labels, what the panel draws) and returns one sentence per panel.
Inside an IPython kernel, importing :mod:`slamlib.viz` makes every matplotlib figure's image
output carry that sentence as its ``alt`` metadata (``{"image/png": {"alt": ...}}``), which the
book's ``_ext/figure_alt.py`` turns into the ``alt`` attribute of the page's ``<img>``. Outside
IPython nothing changes.

matplotlib is not imported here at module level: the display hook finds the formatter of
``matplotlib.figure.Figure`` by name, once matplotlib is loaded.

References
----------
W3C, *Web Content Accessibility Guidelines 2.2*, Success Criterion 1.1.1 (non-text content:
every image has a text alternative that serves the equivalent purpose).
"""

from __future__ import annotations

import re
import sys
import warnings

__all__ = ["describe_figure"]

#: At most this many legend entries are named per legend; the rest are counted.
MAX_LEGEND_ENTRIES = 8

_FIGURE = ("matplotlib.figure", "Figure")
_IMAGE_MIMES = ("image/png", "image/jpeg", "image/svg+xml")
_WRAPPED = "_slamlib_alt_wrapped"

# mathtext commands read aloud as words or plain symbols (other commands lose their backslash)
_TEX_WORDS = {r"\cdot": " times ", r"\times": " times ", r"\leq": " <= ", r"\geq": " >= ", r"\le": " <= ",
              r"\ge": " >= ", r"\pm": " +/- ", r"^\circ": " degrees", r"\circ": " degrees", r"\mid": " | ",
              r"\sim": " ~ ", r"\approx": " approx. ", r"\propto": " proportional to ", r"\infty": "infinity",
              r"\to": " to ", r"\rightarrow": " to ", r"\ldots": "...", r"\dots": "...", r"\,": " ",
              r"\;": " ", r"\!": "", r"\ ": " ", r"\%": "%", r"\{": "{", r"\}": "}"}
_FONT = re.compile(r"\\(?:mathrm|mathbf|mathit|mathcal|mathsf|mathbb|text|textrm|operatorname|boldsymbol|left|right)\b\s*")
_TEX_PATTERNS = [  # applied until nothing changes, innermost groups first
    (re.compile(r"(?<![A-Za-z}])\{([^{}]*)\}"), r"\1"),  # a bare group: x_{hit} -> x_hit
    (re.compile(r"\\(?:d|t)?frac\s*\{([^{}]*)\}\s*\{([^{}]*)\}"), r"(\1)/(\2)"),
    (re.compile(r"\\sqrt\s*\{([^{}]*)\}"), r"sqrt(\1)"),
    (re.compile(r"\\(?:overline|bar)\s*\{([^{}]*)\}"), r"\1-bar"),
    (re.compile(r"\\(hat|tilde|dot)\s*\{([^{}]*)\}"), r"\2-\1"),
]


def _plain(text):
    """Label text without mathtext markup: ``$\\sigma_x \\leq \\sqrt{2}$ [m]`` -> ``sigma_x <= sqrt(2) [m]``."""
    text = str(text)
    if "$" in text:
        for tex, word in sorted(_TEX_WORDS.items(), key=lambda kv: -len(kv[0])):
            end = r"(?![A-Za-z])" if tex[-1].isalpha() else ""  # \le is not the start of \left
            text = re.sub(re.escape(tex) + end, lambda m, w=word: w, text)
        text = _FONT.sub("", text)
        for _ in range(10):
            before = text
            for pattern, repl in _TEX_PATTERNS:
                text = pattern.sub(repl, text)
            if text == before:
                break
        text = re.sub(r"(?<=[A-Za-z0-9])\\([A-Za-z]+)", r" \1", text)  # H\Sigma -> H Sigma
        text = re.sub(r"\\([A-Za-z]+)", r"\1", text)
        text = re.sub(r"[{}$]", "", text)
        text = re.sub(r"([\[(])\s+", r"\1", re.sub(r"\s+([\])])", r"\1", text))
    return re.sub(r"\s+", " ", text).strip()


def _quoted(text):
    return f"'{text}'"


def _is_colorbar(ax):
    return getattr(ax, "_colorbar", None) is not None


def _colorbar_label(cbar):
    ax = cbar.ax
    label = ax.get_ylabel() if getattr(cbar, "orientation", "vertical") == "vertical" else ax.get_xlabel()
    return _plain(label or ax.get_ylabel() or ax.get_xlabel())


def _legend_entries(legend):
    if legend is None or not legend.get_visible():
        return []
    return [t for t in (_plain(txt.get_text()) for txt in legend.get_texts()) if t and not t.startswith("_")]


def _legend_phrase(entries):
    if not entries:
        return ""
    shown = entries[:MAX_LEGEND_ENTRIES]
    more = len(entries) - len(shown)
    return "legend: " + ", ".join(shown) + (f" and {more} more" if more else "")


def _count(n, word):
    return f"{n} {word}{'' if n == 1 else 's'}"


def _drawn(ax):
    """What a panel draws, in words: 'an image, 3 lines, scatter points'."""
    from matplotlib.collections import LineCollection, PatchCollection, PathCollection, PolyCollection, QuadMesh

    parts = []
    if ax.images or any(isinstance(c, QuadMesh) for c in ax.collections):
        parts.append("an image")
    lines = [ln for ln in ax.get_lines() if ln.get_visible()]
    if lines:
        parts.append(_count(len(lines), "line"))
    if any(isinstance(c, PathCollection) and c.get_visible() for c in ax.collections):
        parts.append("scatter points")
    if any(isinstance(c, LineCollection) and c.get_visible() for c in ax.collections):
        parts.append("line segments")
    n_shapes = len([p for p in ax.patches if p.get_visible()])
    n_shapes += sum(1 for c in ax.collections if isinstance(c, (PatchCollection, PolyCollection))
                    and not isinstance(c, QuadMesh) and c.get_visible())
    if n_shapes:
        parts.append(_count(n_shapes, "shape"))
    if not parts and any(t.get_visible() and t.get_text().strip() for t in ax.texts):
        parts.append("text")
    return ", ".join(parts)


def _axis_phrase(ax):
    x, y = _plain(ax.get_xlabel()), _plain(ax.get_ylabel())
    z = _plain(ax.get_zlabel()) if hasattr(ax, "get_zlabel") else ""
    if z:
        return f"{z} over {x or 'x'} and {y or 'y'}"
    if x and y:
        return f"{y} against {x}"
    if y:
        return f"{y} on the vertical axis"
    if x:
        return f"{x} on the horizontal axis"
    return ""


def _panel_sentence(ax, colorbars):
    title = ", ".join(_plain(ax.get_title(loc)) for loc in ("left", "center", "right") if _plain(ax.get_title(loc)))
    details = [p for p in (_axis_phrase(ax), _legend_phrase(_legend_entries(ax.get_legend()))) if p]
    scales = [label for label in (_colorbar_label(cb) for cb in colorbars) if label]
    if scales:
        details.append("colour scale: " + ", ".join(scales))
    elif colorbars:
        details.append("with a colour scale")
    drawn = _drawn(ax)
    if drawn:
        details.append("draws " + drawn)
    return (_quoted(title) if title else ""), "; ".join(details)


def describe_figure(fig):
    """A text alternative of a matplotlib figure, read from the figure's own content.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure to describe.

    Returns
    -------
    str
        For example ``"Figure with 2 panels. Panel 1, 'Belief after 3 updates': probability
        against cell; legend: belief, true position; draws 2 lines. Panel 2, ..."``; a single
        panel reads ``"Plot 'title': ..."``. Each visible panel gives its title, its axis labels
        (y against x), its legend entries (at most `MAX_LEGEND_ENTRIES`), the labels of the colour
        scales drawn for it and what it draws (an image, lines, scatter points, shapes);
        colour-bar axes and empty panels (no title, no labels, nothing drawn) are not counted as
        panels. The suptitle and figure legends come first; mathtext is read as plain text
        (``$\\sigma_x$`` -> ``sigma_x``).

    Raises
    ------
    TypeError
        If `fig` is not a matplotlib Figure.
    """
    from matplotlib.figure import Figure

    if not isinstance(fig, Figure):
        raise TypeError(f"fig must be a matplotlib.figure.Figure, got {type(fig).__name__}")
    axes = [ax for ax in fig.get_axes() if ax.get_visible()]
    colorbars = [ax._colorbar for ax in axes if _is_colorbar(ax)]
    panels = [ax for ax in axes if not _is_colorbar(ax)]
    by_panel = {id(ax): [] for ax in panels}
    loose = []
    for cb in colorbars:
        owner = getattr(getattr(cb, "mappable", None), "axes", None)
        (by_panel[id(owner)] if id(owner) in by_panel else loose).append(cb)

    # a panel with no title, no labels and nothing drawn (a spacer) is not described
    said = [(title, details) for title, details in (_panel_sentence(ax, by_panel[id(ax)]) for ax in panels)
            if title or details]
    suptitle = _plain(fig.get_suptitle())
    fig_legend = _legend_phrase([e for lg in fig.legends for e in _legend_entries(lg)])
    loose_scales = [label for label in (_colorbar_label(cb) for cb in loose) if label]

    if len(said) == 1 and not loose:
        title, details = said[0]
        details = "; ".join(p for p in (details, fig_legend) if p)
        text = (f"Plot {title}" if title else "Untitled plot") + (f": {details}" if details else "") + "."
        return (f"{_quoted(suptitle)}. " if suptitle else "") + text

    head = "Empty figure" if not said else f"Figure with {_count(len(said), 'panel')}"
    if suptitle:
        head += f", {_quoted(suptitle)}"
    sentences = [head]
    if fig_legend:
        sentences.append(fig_legend[0].upper() + fig_legend[1:])
    if loose_scales:
        sentences.append("Colour scale: " + ", ".join(loose_scales))
    for k, (title, details) in enumerate(said, start=1):
        sentences.append(f"Panel {k}" + (f", {title}" if title else "") + (f": {details}" if details else ""))
    return ". ".join(sentences) + "."


# --- IPython: the figure's image output carries the description as its alt metadata ---------------

def _with_alt(printer):
    """`printer` (a formatter function of Figure) whose output also carries ``{"alt": ...}``."""

    def printer_with_alt(fig, *args, **kwargs):
        out = printer(fig, *args, **kwargs)
        if out is None:
            return None
        data, md = out if isinstance(out, tuple) and len(out) == 2 else (out, None)
        md = dict(md or {})
        if "alt" not in md:
            try:
                md["alt"] = describe_figure(fig)
            except Exception as exc:  # the figure is shown all the same; the book's browser test reports it
                warnings.warn(f"slamlib.viz could not describe the figure ({type(exc).__name__}: {exc}); "
                              "its image has no text alternative", RuntimeWarning, stacklevel=2)
        return data, md

    setattr(printer_with_alt, _WRAPPED, True)
    printer_with_alt.__wrapped__ = printer
    return printer_with_alt


def wrap_figure_formatters(shell):
    """Wrap the image formatters of ``matplotlib.figure.Figure`` in `shell` that are not wrapped yet.

    Returns the MIME types newly wrapped. Does nothing before matplotlib is imported.
    """
    if "matplotlib.figure" not in sys.modules:
        return []
    from matplotlib.figure import Figure

    done = []
    for mime in _IMAGE_MIMES:
        formatter = shell.display_formatter.formatters.get(mime)
        if formatter is None:
            continue
        try:
            printer = formatter.lookup_by_type(Figure)
        except KeyError:
            continue
        if getattr(printer, _WRAPPED, False):
            continue
        formatter.for_type(Figure, _with_alt(printer))
        done.append(mime)
    return done


def _post_execute(shell):
    def wrap_before_display():
        wrap_figure_formatters(shell)

    wrap_before_display.__qualname__ = "slamlib.viz.wrap_figure_formatters"
    return wrap_before_display


def install(shell=None):
    """Make every matplotlib figure displayed by the IPython `shell` carry its description.

    The inline backend registers its PNG formatter when pyplot is first imported, which may come
    before or after this call, and again when its figure formats change; so the formatters are
    wrapped now and after every cell, by a ``post_execute`` callback that runs *before* the inline
    backend's ``flush_figures`` (which displays the cell's figures). Idempotent; does nothing
    outside IPython. Returns True when installed.
    """
    if shell is None:
        ipython = sys.modules.get("IPython")
        shell = ipython.get_ipython() if ipython is not None else None
    if shell is None or not hasattr(shell, "events") or not hasattr(shell, "display_formatter"):
        return False
    callbacks = shell.events.callbacks["post_execute"]
    if not any(getattr(cb, _WRAPPED, False) for cb in callbacks):
        cb = _post_execute(shell)
        setattr(cb, _WRAPPED, True)
        shell.events.register("post_execute", cb)
        if cb in callbacks:
            callbacks.remove(cb)
            callbacks.insert(0, cb)  # before matplotlib_inline's flush_figures
    wrap_figure_formatters(shell)
    return True
