"""The reader's copy: the whole book as one PDF, printed by headless Chromium.

Build the single-page HTML first (it reuses the execution cache of the HTML build, so no chapter
runs again), then print it::

    jupyter-book build . --builder singlehtml
    python tools/book_pdf.py            # writes _build/pdf/book.pdf

The page is served on localhost, MathJax is awaited, every image must have loaded, and Chromium's
DevTools ``Page.printToPDF`` prints it (A4, with the page's print styles). ``check_pdf`` (used by
``tests/test_book_browser.py``) then reads the PDF back with ``pypdf``: every chapter's title is in
its text and it holds at least as many images as the single page has figures.
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import functools
import http.server
import json
import re
import shutil
import sys
import tempfile
import threading
import time
import unicodedata
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SINGLE = ROOT / "_build" / "singlehtml"
OUT = ROOT / "_build" / "pdf" / "book.pdf"

# polled from Python (short calls: typesetting the whole book's mathematics takes a while)
_STATE = """
if (!window.__slamPdf) {
  window.__slamPdf = {done: false, error: null};
  const start = () => {
    const mj = window.MathJax && MathJax.startup && MathJax.startup.promise;
    if (document.querySelector('script[src*="mathjax"]') && !mj) { setTimeout(start, 200); return; }
    (mj || Promise.resolve()).then(() => { window.__slamPdf.done = true; })
      .catch(e => { window.__slamPdf.error = String(e); });
  };
  start();
}
const imgs = Array.from(document.images);
return {done: window.__slamPdf.done && imgs.every(i => i.complete), error: window.__slamPdf.error,
        images: imgs.length, broken: imgs.filter(i => i.complete && !(i.naturalWidth > 0)).map(i => i.src)};
"""


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


@contextlib.contextmanager
def serve(directory: Path):
    """Serve ``directory`` on an ephemeral localhost port; yields the base URL."""
    handler = functools.partial(_QuietHandler, directory=str(directory))
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{httpd.server_address[1]}"
    finally:
        httpd.shutdown()


def chrome_driver():
    """A headless Chromium driven by selenium (Debian's chromium and chromium-driver)."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    chrome = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    chromedriver = shutil.which("chromedriver")
    if not chrome or not chromedriver:
        raise RuntimeError("Chromium and ChromeDriver are required (apt-get install chromium chromium-driver)")
    profile = tempfile.mkdtemp(prefix="slam-book-pdf-")
    opts = webdriver.ChromeOptions()
    opts.binary_location = chrome
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                "--disable-background-networking", "--disable-component-update", "--disable-sync",
                "--disable-dev-shm-usage", "--window-size=1280,1600", f"--user-data-dir={profile}"):
        opts.add_argument(arg)
    drv = webdriver.Chrome(service=Service(chromedriver), options=opts)
    drv.set_page_load_timeout(300)
    drv.set_script_timeout(60)
    drv._slam_profile = profile
    return drv


def single_page(single: Path = SINGLE, root: Path = ROOT) -> Path:
    """The single-page build's page: the book's root document (``index.html`` only redirects)."""
    m = re.search(r"^root:\s*(\S+)", (root / "_toc.yml").read_text(encoding="utf-8"), flags=re.M)
    page = single / f"{m.group(1)}.html"
    if not page.is_file():
        raise FileNotFoundError(f"{page} is missing: run  jupyter-book build . --builder singlehtml")
    return page


def print_pdf(single: Path = SINGLE, out: Path = OUT, *, timeout: float = 900.0) -> dict:
    """Print the single-page build to ``out``; returns what the page reported (image count)."""
    page = single_page(single)
    # the single page's links are relative to the build's top folder, where Sphinx does not put it
    top = single / "book.html"
    shutil.copyfile(page, top)
    drv = chrome_driver()
    try:
        with serve(single) as url:
            drv.get(f"{url}/{top.name}")
            t0 = time.monotonic()
            while True:
                state = drv.execute_script(_STATE)
                if state["broken"]:
                    raise RuntimeError(f"images that did not load: {state['broken'][:5]}")
                if state["error"]:
                    raise RuntimeError(f"MathJax failed on the single page: {state['error']}")
                if state["done"]:
                    break
                if time.monotonic() - t0 > timeout:
                    raise RuntimeError(f"the single page did not finish rendering in {timeout:.0f} s")
                time.sleep(1.0)
            if state["broken"]:
                raise RuntimeError(f"images that did not load: {state['broken'][:5]}")
            pdf = drv.execute_cdp_cmd("Page.printToPDF", {
                "printBackground": True, "paperWidth": 8.27, "paperHeight": 11.69,
                "marginTop": 0.6, "marginBottom": 0.6, "marginLeft": 0.5, "marginRight": 0.5,
                "displayHeaderFooter": True, "headerTemplate": "<span></span>",
                "footerTemplate": ('<div style="font-size:8px;width:100%;text-align:center">'
                                   '<span class="pageNumber"></span> / <span class="totalPages"></span></div>'),
            })
    finally:
        drv.quit()
        shutil.rmtree(drv._slam_profile, ignore_errors=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(base64.b64decode(pdf["data"]))
    return {"images": state["images"], "path": str(out)}


def chapter_titles(root: Path = ROOT) -> dict[str, str]:
    """The first heading of every page in ``_toc.yml``, keyed by its path."""
    import nbformat

    toc = (root / "_toc.yml").read_text(encoding="utf-8")
    titles = {}
    for page in re.findall(r"^\s*(?:root|- file):\s*(\S+)", toc, flags=re.M):
        for suffix in (".ipynb", ".md"):
            path = root / (page + suffix)
            if path.is_file():
                break
        else:
            raise FileNotFoundError(f"_toc.yml names {page}, which has no .ipynb or .md file")
        if path.suffix == ".ipynb":
            nb = nbformat.read(path, as_version=4)
            text = "\n".join(c.source for c in nb.cells if c.cell_type == "markdown")
        else:
            text = path.read_text(encoding="utf-8")
        m = re.search(r"^#\s+(.+?)\s*$", text, flags=re.M)
        if not m:
            raise ValueError(f"{path}: no top-level heading")
        titles[page] = m.group(1)
    return titles


def _words(text: str) -> str:
    """Letters and digits only, lower case, ligatures undone: PDF text extraction splits and joins
    words freely and keeps the typeface's ligatures ("ﬁ")."""
    return re.sub(r"[^0-9a-z]+", "", unicodedata.normalize("NFKC", text).lower())


def check_pdf(pdf: Path = OUT, single: Path = SINGLE, root: Path = ROOT) -> dict:
    """What is missing from the PDF: chapter titles not in its text, figures not in its images."""
    from pypdf import PdfReader

    reader = PdfReader(str(pdf))
    text = _words(" ".join(page.extract_text() or "" for page in reader.pages))
    n_images = sum(len(page.images) for page in reader.pages)
    html = single_page(single, root).read_text(encoding="utf-8")
    # figures of the book: the images inside its article (not the logo or the theme's icons)
    body = html.split('<article', 1)[-1]
    n_figures = len(re.findall(r"<img\b", body))
    missing = [page for page, title in chapter_titles(root).items()
               if _words(re.sub(r"[`*_{}\[\]]|\(.*?\)", " ", title)) not in text]
    return {"pages": len(reader.pages), "images": n_images, "figures": n_figures, "missing_titles": missing}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--single", type=Path, default=SINGLE, help="folder of the singlehtml build")
    ap.add_argument("-o", "--out", type=Path, default=OUT, help="the PDF to write")
    args = ap.parse_args(argv)
    info = print_pdf(args.single, args.out)
    facts = check_pdf(args.out, args.single)
    print(json.dumps({**info, **facts}, indent=1))
    ok = not facts["missing_titles"] and facts["images"] >= facts["figures"]
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
