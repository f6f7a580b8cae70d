"""Every figure with a text alternative: the ``alt`` of a notebook output's image comes from the output.

MyST-NB renders an image output of a notebook cell as an image node without ``alt`` (the HTML
writer then falls back to the file's path, useless to a screen reader), naming the file by the
sha256 of the image's bytes (``myst_nb/core/render.py``, ``render_image``). In the kernel,
``slamlib.viz`` gives every matplotlib figure's image output a description of the figure as
output metadata, ``{"image/png": {"alt": "..."}}``. After a document is read, this extension maps
sha256 -> alt over the outputs of the executed notebook MyST-NB wrote
(``_build/jupyter_execute/<docname>.ipynb``) and of the document's run in the execution cache
(where MyST-NB took the outputs from the cache, the notebook it writes has none; for images glued
from elsewhere, over every executed notebook) and sets the ``alt`` of each image node whose ``alt`` is missing or is its own path;
once more when the document is resolved, for images pasted after reading.
An alt an author set (cell metadata ``mystnb: image: alt:``) is kept; an image whose output has
no alt metadata is left as it is (the browser test reports it).
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
import re
from pathlib import Path

from sphinx.util import logging

logger = logging.getLogger(__name__)

_BASE64_MIMES = ("image/png", "image/jpeg", "image/gif")
_TEXT_MIMES = ("image/svg+xml",)
_GLUE_PREFIX = "application/papermill.record/"


def _image_bytes(mime, content):
    """The bytes MyST-NB hashes for an output of type `mime` (as in its ``render_image``)."""
    if isinstance(content, list):
        content = "".join(content)
    if mime in _BASE64_MIMES:
        return base64.b64decode(content)
    return os.linesep.join(content.splitlines()).encode("utf-8")


def alt_by_hash(notebook) -> dict[str, str]:
    """sha256 hex digest of each image output's bytes -> its ``alt`` metadata.

    `notebook` is an executed notebook as a dict (nbformat 4 JSON). Images glued with
    ``myst_nb.glue`` (MIME types under ``application/papermill.record/``) count as well.
    """
    found = {}
    for cell in notebook.get("cells", []):
        for output in cell.get("outputs", []) or []:
            data, meta = output.get("data") or {}, output.get("metadata") or {}
            for key, content in data.items():
                mime = key[len(_GLUE_PREFIX):] if key.startswith(_GLUE_PREFIX) else key
                if mime not in _BASE64_MIMES + _TEXT_MIMES:
                    continue
                md = meta.get(key) or meta.get(mime) or {}
                alt = md.get("alt") if isinstance(md, dict) else None
                if not isinstance(alt, str) or not alt.strip():
                    continue
                try:
                    digest = hashlib.sha256(_image_bytes(mime, content)).hexdigest()
                except (ValueError, TypeError):
                    continue
                found[digest] = alt.strip()
    return found


def _read_alts(path: Path) -> dict[str, str]:
    try:
        return alt_by_hash(json.loads(path.read_text(encoding="utf-8")))
    except (OSError, ValueError):
        return {}


def _output_hash(node):
    """The sha256 naming the file of a notebook output's image node, or None for other images."""
    stem = Path(node.get("uri", "")).stem
    return stem if re.fullmatch(r"[0-9a-f]{64}", stem) else None


def _needs_alt(node) -> bool:
    alt, uri = node.get("alt"), node.get("uri", "")
    return not alt or alt == uri or alt.endswith(Path(uri).name)


def set_alts(doctree, alts: dict[str, str], more=None) -> tuple[int, int]:
    """Set the ``alt`` of the image nodes in `doctree` named by a hash in `alts`.

    `more` (optional) is called once, with no argument, when a node's hash is not in `alts`,
    and returns further hash -> alt entries. Returns (images set, images that needed an alt).
    """
    from docutils import nodes

    done = needed = 0
    for node in doctree.findall(nodes.image):
        digest = _output_hash(node)
        if digest is None or not _needs_alt(node):
            continue
        needed += 1
        if digest not in alts and more is not None:
            alts.update(more())
            more = None
        if digest in alts:
            node["alt"] = alts[digest]
            done += 1
    return done, needed


def _executed_folder(app):
    config = getattr(app.env, "mystnb_config", None)
    folder = getattr(config, "output_folder", None)
    return Path(folder) if folder else Path(app.outdir).parent / "jupyter_execute"


def _cached_alts(app, docname) -> dict[str, str]:
    """The alts of the document's run in the execution cache.

    When MyST-NB takes a notebook's outputs from the cache (``execute_notebooks: cache``; the
    notebook tests fill that cache, see ``chapters/conftest.py``), the notebook it writes to
    ``jupyter_execute`` is the unexecuted one: the outputs are only in the cache's copy.
    """
    config = getattr(app.env, "mystnb_config", None)
    cache_path = (getattr(config, "execution_cache_path", None)
                  or getattr(getattr(app, "config", None), "nb_execution_cache_path", None))
    doc2path = getattr(app.env, "doc2path", None)
    if not cache_path or doc2path is None or not Path(cache_path).is_dir():
        return {}
    source = Path(doc2path(docname))
    if source.suffix != ".ipynb":
        return {}
    try:
        import nbformat
        from jupyter_cache import get_cache

        cache = get_cache(str(cache_path))
        record = cache.match_cache_notebook(nbformat.read(source, as_version=4))
        notebook = cache.get_cache_bundle(record.pk).nb
    except Exception:  # noqa: BLE001 - no cached run (KeyError), or an unreadable cache: nothing to add
        return {}
    return alt_by_hash(nbformat.from_dict(notebook))


def _fill(app, doctree, docname):
    folder = _executed_folder(app)
    own = folder.joinpath(*(docname + ".ipynb").split("/"))
    alts = _read_alts(own) if own.is_file() else {}
    alts.update(_cached_alts(app, docname))

    def everywhere():
        found = {}
        for path in sorted(folder.rglob("*.ipynb")):
            if path != own:
                found.update(_read_alts(path))
        return found

    done, needed = set_alts(doctree, alts, more=everywhere)
    if needed:
        logger.verbose(f"figure_alt: {docname}: {done} of {needed} images got a text alternative")


def _doctree_read(app, doctree):
    _fill(app, doctree, app.env.docname)


def _doctree_resolved(app, doctree, docname):
    # images pasted after reading (glued figures from another document) get theirs here
    _fill(app, doctree, docname)


def setup(app):
    app.connect("doctree-read", _doctree_read)
    app.connect("doctree-resolved", _doctree_resolved)
    return {"version": "1.0", "parallel_read_safe": True, "parallel_write_safe": True}
