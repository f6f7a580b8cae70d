"""Every figure with a text alternative: slamlib.viz.describe_figure, the IPython display hook that
puts it in a figure's image output metadata, and the book's _ext/figure_alt.py that moves it into
the page's <img alt>."""

import base64
import hashlib
import importlib.util
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import nbformat  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from docutils import nodes  # noqa: E402

import slamlib.viz as viz  # noqa: E402
from slamlib.viz import _describe  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def fig():
    f = plt.figure()
    yield f
    plt.close(f)


# --- describe_figure ---------------------------------------------------------------------------

def test_two_panels_with_titles_labels_legend_and_colorbar(fig):
    fig.suptitle("Histogram filter")
    a, b = fig.subplots(1, 2)
    a.plot([0.1, 0.9], label="belief")
    a.plot([0.0, 1.0], label="true position")
    a.legend()
    a.set(title="Belief after 3 updates", xlabel="cell", ylabel="probability")
    im = b.imshow(np.eye(3))
    fig.colorbar(im, ax=b, label=r"$p(m_i)$")
    b.set(title="Map", xlabel="x [m]", ylabel="y [m]")
    text = viz.describe_figure(fig)
    assert text == ("Figure with 2 panels, 'Histogram filter'. "
                    "Panel 1, 'Belief after 3 updates': probability against cell; legend: belief, true position; "
                    "draws 2 lines. "
                    "Panel 2, 'Map': y [m] against x [m]; colour scale: p(m_i); draws an image.")
    assert len(fig.get_axes()) == 3  # the colour bar is an axes, not a panel


def test_single_panel_reads_as_a_plot(fig):
    ax = fig.subplots()
    ax.scatter([0, 1], [1, 0], label="particles")
    ax.plot([0, 1], [0, 1], label=r"$\sigma_x \leq 2$")
    ax.legend()
    ax.set_xlabel("x [m]")
    assert viz.describe_figure(fig) == ("Untitled plot: x [m] on the horizontal axis; "
                                        "legend: particles, sigma_x <= 2; draws 1 line, scatter points.")


def test_hidden_panels_are_skipped_and_long_legends_counted(fig):
    a, b = fig.subplots(1, 2)
    b.set_visible(False)
    for k in range(_describe.MAX_LEGEND_ENTRIES + 3):
        a.plot([0, k], label=f"run {k}")
    a.legend()
    a.set_title("Runs")
    text = viz.describe_figure(fig)
    assert text.startswith("Plot 'Runs': legend: run 0, run 1,")
    assert "run 7 and 3 more" in text and "run 8" not in text
    assert "Panel" not in text


def test_spacer_panels_are_not_counted(fig):
    a, spacer, c = fig.subplots(1, 3)
    spacer.axis("off")
    a.plot([0, 1])
    c.set_title("Right")
    assert viz.describe_figure(fig) == "Figure with 2 panels. Panel 1: draws 1 line. Panel 2, 'Right'."
    c.remove()
    assert viz.describe_figure(fig) == "Untitled plot: draws 1 line."


@pytest.mark.parametrize("label, plain", [
    (r"$\overline{bel}(x)$", "bel-bar(x)"),
    (r"$y = \sin\theta$", "y = sin theta"),
    (r"mixture $p(z \mid z^*)$", "mixture p(z | z^*)"),
    (r"bound $\sqrt{f(1-f)}$", "bound sqrt(f(1-f))"),
    (r"$\frac{a}{b}$ and $\mathrm{N}(0, 1)$", "(a)/(b) and N(0, 1)"),
    (r"heading [$^\circ$]", "heading [degrees]"),
    (r"$\hat{x}_t$, $2\sigma$ ellipse", "x-hat_t, 2 sigma ellipse"),
    (r"std $\sqrt{\mathrm{Var}\,m_x + \mathrm{Var}\,m_y}$ [m]", "std sqrt(Var m_x + Var m_y) [m]"),
    (r"$S = H\Sigma H^T + Q$, $\exp(-d^2 / 2\sigma_{hit}^2)$", "S = H Sigma H^T + Q, exp(-d^2 / 2 sigma_hit^2)"),
    (r"$|2\pi S|^{-1/2} e^{-\nu^T Q^{-1} \nu / 2}$", "|2 pi S|^-1/2 e^-nu^T Q^-1 nu / 2"),
    ("50% of runs", "50% of runs"),
])
def test_mathtext_is_read_as_plain_text(fig, label, plain):
    fig.subplots().set_title(label)
    assert viz.describe_figure(fig) == f"Plot '{plain}'."


def test_figure_legend_and_empty_figure(fig):
    assert viz.describe_figure(fig) == "Empty figure."
    a, b = fig.subplots(1, 2)
    a.plot([0, 1], label="EKF")
    b.plot([1, 0], label="UKF")
    fig.legend()
    assert viz.describe_figure(fig).startswith("Figure with 2 panels. Legend: EKF, UKF. Panel 1: draws 1 line.")


def test_describe_figure_rejects_non_figures(fig):
    ax = fig.subplots()
    with pytest.raises(TypeError, match="fig must be a matplotlib.figure.Figure, got Axes"):
        viz.describe_figure(ax)


# --- the display hook --------------------------------------------------------------------------

def test_wrapped_printer_adds_alt_and_keeps_given_metadata(fig):
    fig.subplots().set_title("Pose")
    plain = _describe._with_alt(lambda f: "PNGDATA")
    assert plain(fig) == ("PNGDATA", {"alt": "Plot 'Pose'."})
    retina = _describe._with_alt(lambda f: ("PNGDATA", {"width": 10, "height": 5}))
    assert retina(fig) == ("PNGDATA", {"width": 10, "height": 5, "alt": "Plot 'Pose'."})
    authored = _describe._with_alt(lambda f: ("PNGDATA", {"alt": "An author's words."}))
    assert authored(fig) == ("PNGDATA", {"alt": "An author's words."})
    assert _describe._with_alt(lambda f: None)(fig) is None


def test_a_figure_that_cannot_be_described_is_shown_without_alt(fig, monkeypatch):
    def broken(f):
        raise ValueError("unexpected artist")

    monkeypatch.setattr(_describe, "describe_figure", broken)
    with pytest.warns(RuntimeWarning, match="could not describe the figure .ValueError: unexpected artist"):
        assert _describe._with_alt(lambda f: ("PNGDATA", {"width": 3}))(fig) == ("PNGDATA", {"width": 3})


def test_install_does_nothing_outside_ipython():
    assert _describe.install() is False


def _kernel_env(monkeypatch):
    monkeypatch.setenv("PYTHONPATH", str(ROOT))  # the kernel imports this tree's slamlib
    # the kernel draws with the inline backend, as in the book (conftest's Agg would draw nothing)
    monkeypatch.setenv("MPLBACKEND", "module://matplotlib_inline.backend_inline")


@pytest.mark.slow
def test_executed_notebook_outputs_carry_alt(tmp_path, monkeypatch):
    """In a real kernel, whether slamlib.viz is imported before or after pyplot, each figure's PNG
    output carries its description; a figure displayed before the import does not."""
    from nbclient import NotebookClient

    _kernel_env(monkeypatch)
    cells = [
        "import matplotlib.pyplot as plt\nfig, ax = plt.subplots()\nax.set_title('Before slamlib.viz');",
        "import slamlib as sl\nfig, ax = plt.subplots()\nsl.viz.plot_pose([0, 0, 0], ax=ax)\n"
        "ax.set(title='Robot pose', xlabel='x [m]', ylabel='y [m]');",
        "fig, ax = plt.subplots(1, 2)\nax[0].plot([1, 2], label='belief')\nax[0].legend()\n"
        "ax[1].set_title('Map');",
        "%config InlineBackend.figure_formats = ['retina']\nfig, ax = plt.subplots()\nax.set_title('Retina');",
    ]
    nb = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(c) for c in cells])
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    NotebookClient(nb, kernel_name="python3", timeout=120, resources={"metadata": {"path": str(tmp_path)}}).execute()
    pngs = [[o.get("metadata", {}).get("image/png", {}) for o in c.outputs if "image/png" in o.get("data", {})]
            for c in nb.cells]
    assert [len(p) for p in pngs] == [1, 1, 1, 1]
    assert "alt" not in pngs[0][0]
    assert pngs[1][0]["alt"] == "Plot 'Robot pose': y [m] against x [m]; draws 1 shape."
    assert pngs[2][0]["alt"] == "Figure with 2 panels. Panel 1: legend: belief; draws 1 line. Panel 2, 'Map'."
    assert pngs[3][0]["alt"] == "Plot 'Retina'." and pngs[3][0]["width"] > 0


@pytest.mark.slow
def test_imported_before_pyplot_in_a_kernel(tmp_path, monkeypatch):
    from nbclient import NotebookClient

    _kernel_env(monkeypatch)
    cells = ["import slamlib.viz", "import matplotlib.pyplot as plt\nplt.plot([0, 1])\nplt.title('First figure');"]
    nb = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(c) for c in cells])
    NotebookClient(nb, kernel_name="python3", timeout=120, resources={"metadata": {"path": str(tmp_path)}}).execute()
    (out,) = [o for o in nb.cells[1].outputs if "image/png" in o.get("data", {})]
    assert out["metadata"] == {"image/png": {"alt": "Plot 'First figure': draws 1 line."}}


# --- the book's extension ----------------------------------------------------------------------

def _load_extension():
    spec = importlib.util.spec_from_file_location("figure_alt", ROOT / "_ext" / "figure_alt.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _image_output(png, alt=None, prefix=""):
    md = {"image/png": {"alt": alt}} if alt else {}
    return nbformat.v4.new_output("display_data", data={prefix + "image/png": base64.b64encode(png).decode(),
                                                       prefix + "text/plain": "<Figure>"}, metadata=md)


def test_extension_maps_image_hashes_to_alt():
    ext = _load_extension()
    a, b, c, g = b"\x89PNG a", b"\x89PNG b", b"\x89PNG c", b"\x89PNG glued"
    svg = '<svg xmlns="http://www.w3.org/2000/svg">\n<rect/>\n</svg>'
    cell = nbformat.v4.new_code_cell("...")
    cell.outputs = [_image_output(a, "Plot 'A'."), _image_output(b),
                    _image_output(g, "Plot 'Glued'.", prefix="application/papermill.record/"),
                    nbformat.v4.new_output("display_data", data={"image/svg+xml": svg},
                                           metadata={"image/svg+xml": {"alt": "Vector figure."}})]
    nb = nbformat.v4.new_notebook(cells=[nbformat.v4.new_markdown_cell("text"), cell])
    alts = ext.alt_by_hash(nbformat.from_dict(nb))
    sha = lambda data: hashlib.sha256(data).hexdigest()  # noqa: E731
    assert alts == {sha(a): "Plot 'A'.", sha(g): "Plot 'Glued'.", sha(svg.encode()): "Vector figure."}

    doc = nodes.document(None, None)
    folder = "/_build/jupyter_execute/"
    images = [nodes.image(uri=folder + sha(a) + ".png"),  # gets its alt
              nodes.image(uri=folder + sha(a) + ".png", alt="Set by the author."),  # keeps it
              nodes.image(uri=folder + sha(b) + ".png"),  # no alt metadata: left
              nodes.image(uri=folder + sha(g) + ".png", alt=folder + sha(g) + ".png"),  # its path: replaced
              nodes.image(uri="_static/logo.svg"),  # not a notebook output: ignored
              nodes.image(uri=folder + sha(c) + ".png")]  # found by the fallback
    for image in images:
        doc += image
    calls = []

    def more():
        calls.append(1)
        return {sha(c): "From another page."}

    assert ext.set_alts(doc, alts, more=more) == (3, 4)
    assert [i.get("alt") for i in images] == ["Plot 'A'.", "Set by the author.", None, "Plot 'Glued'.", None,
                                             "From another page."]
    assert calls == [1]


def test_extension_reads_the_executed_notebook_of_the_document(tmp_path):
    """As wired into Sphinx: the document's executed notebook first, then the other notebooks
    (a figure glued in one chapter and pasted in another page)."""
    from types import SimpleNamespace

    ext = _load_extension()
    own, other = b"\x89PNG own", b"\x89PNG other"
    for name, png, alt in (("chapters/01_x.ipynb", own, "Plot 'Own'."),
                           ("chapters/02_y.ipynb", other, "Plot 'Other'.")):
        cell = nbformat.v4.new_code_cell("...")
        cell.outputs = [_image_output(png, alt)]
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        nbformat.write(nbformat.v4.new_notebook(cells=[cell]), tmp_path / name)
    app = SimpleNamespace(env=SimpleNamespace(mystnb_config=SimpleNamespace(output_folder=str(tmp_path)),
                                              docname="chapters/01_x"), outdir=str(tmp_path / "html"))
    uri = lambda data: f"/_build/jupyter_execute/{hashlib.sha256(data).hexdigest()}.png"  # noqa: E731
    for docname in ("chapters/01_x", "index"):  # a notebook page, a page without a notebook
        doc = nodes.document(None, None)
        doc += nodes.image(uri=uri(own))
        doc += nodes.image(uri=uri(other))
        app.env.docname = docname
        ext._doctree_read(app, doc)
        assert [i["alt"] for i in doc.findall(nodes.image)] == ["Plot 'Own'.", "Plot 'Other'."]
