"""Drive headless Chromium over every page of the built book.

Run after ``jupyter-book build .``::

    SLAM_BOOK_BROWSER=1 python -m pytest -m browser tests/test_book_browser.py

It serves ``_build/html`` on localhost and checks, page by page: HTTP 200, no
JavaScript errors in the console, nothing fetched from outside localhost (the
book must read offline), MathJax finished with no unrendered TeX and no TeX
errors, every ``<img>`` loaded, every image of the text (animation frames aside) with a
text alternative that is not a file path and has at least 15 characters (``_ext/figure_alt.py``),
every animation's controls present with its first frame drawn, no favicon request failing, a
logo and exactly one search box;
nothing wider than the text column (see below); and the search page finds
"particle". Screenshots of a few pages go to ``artifacts/screenshots``.

Accessibility: axe-core (the npm package, installed by ``.ci/browser`` into ``.ci-node``, or the
file named by ``SLAM_AXE_JS``) runs on every page with its default rules; no violation of impact
"serious" or "critical" is allowed.

The reader's copy: ``tools/book_pdf.py`` prints the single-page HTML build to a PDF, which must
hold every chapter's title and at least as many images as the book has figures.

Horizontal overflow, in a 1280 px wide window: the page itself never scrolls
sideways; no element reaches outside the article's text column unless it sits in
a box that scrolls horizontally (wide tables); a code cell or output never hides
text behind a scrollbar (long lines wrap, see ``_static/custom.css``); and a
displayed equation is never clipped and fits the column (the chapters break long
equations over lines).

Without a built book or Chromium the tests are skipped, unless
``SLAM_BOOK_BROWSER=1`` (set by ``.ci/browser``), which turns a missing
prerequisite into a failure.
"""

from __future__ import annotations

import functools
import http.server
import os
import re
import shutil
import tempfile
import threading
import urllib.request
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
HTML = ROOT / "_build" / "html"
SHOTS = ROOT / "artifacts" / "screenshots"
REQUIRED = os.environ.get("SLAM_BOOK_BROWSER") == "1"
SCREENSHOT_PAGES = {"chapters/00_intro", "chapters/02_motion_sensor_models", "chapters/05_mcl",
                    "chapters/07_ekf_slam", "chapters/09_real_data_mrclam", "chapters/algorithm_index"}

AXE_JS = Path(os.environ.get("SLAM_AXE_JS") or ROOT / ".ci-node" / "node_modules" / "axe-core" / "axe.min.js")
SINGLE = ROOT / "_build" / "singlehtml"

pytestmark = pytest.mark.browser


def _missing(reason):
    if REQUIRED:
        pytest.fail(reason)
    pytest.skip(reason)


def toc_pages():
    text = (ROOT / "_toc.yml").read_text(encoding="utf-8")
    return re.findall(r"^\s*(?:root|- file):\s*(\S+)", text, flags=re.M)


@pytest.fixture(scope="module")
def server():
    if not (HTML / "index.html").is_file():
        _missing("no built book: run  jupyter-book build .  first")
    handler = functools.partial(_QuietHandler, directory=str(HTML))
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{httpd.server_address[1]}"
    httpd.shutdown()


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


@pytest.fixture(scope="module")
def driver():
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service
    except ImportError:
        _missing("selenium is not installed (python -m pip install -e '.[dev]')")
    chrome = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    chromedriver = shutil.which("chromedriver")
    if not chrome or not chromedriver:
        _missing("Chromium and ChromeDriver are not installed (apt-get install chromium chromium-driver)")
    profile = tempfile.mkdtemp(prefix="slam-book-chromium-")
    opts = webdriver.ChromeOptions()
    opts.binary_location = chrome
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                "--disable-background-networking", "--disable-component-update", "--disable-sync",
                "--disable-dev-shm-usage", "--window-size=1280,1600", f"--user-data-dir={profile}"):
        opts.add_argument(arg)
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    drv = webdriver.Chrome(service=Service(chromedriver), options=opts)
    drv.set_page_load_timeout(60)
    drv.set_script_timeout(60)
    yield drv
    drv.quit()
    shutil.rmtree(profile, ignore_errors=True)


# JavaScript run in the page once it has loaded
_WAIT_MATHJAX = """
const done = arguments[arguments.length - 1];
if (!document.querySelector('script[src*="mathjax"]')) { done('no-mathjax'); return; }
const t0 = Date.now();
(function poll() {
  if (window.MathJax && MathJax.startup && MathJax.startup.promise) {
    MathJax.startup.promise.then(() => done('ok')).catch(e => done('error: ' + e));
  } else if (Date.now() - t0 > 30000) { done('timeout'); } else { setTimeout(poll, 100); }
})();
"""

_PAGE_FACTS = """
const clone = document.querySelector('main') ? document.querySelector('main').cloneNode(true) : document.body.cloneNode(true);
clone.querySelectorAll('pre, code, script, style, mjx-container, .highlight, textarea').forEach(e => e.remove());
const imgs = Array.from(document.images).map(i => ({src: i.currentSrc || i.src, ok: i.complete && i.naturalWidth > 0}));
const anims = Array.from(document.querySelectorAll('.animation')).map(a => {
  const img = a.querySelector('img');
  return {controls: a.querySelectorAll('.anim-buttons button, button').length,
          slider: !!a.querySelector('input[type=range]'),
          frame: !!(img && img.complete && img.naturalWidth > 0)};
});
const resources = performance.getEntriesByType('resource').map(r => r.name);
const article = document.querySelector('article.bd-article') || document.querySelector('main') || document.body;
const figs = Array.from(article.querySelectorAll('img')).filter(i => !i.closest('.animation'))
  .map(i => ({src: i.getAttribute('src'), alt: i.getAttribute('alt')}));
return {text: clone.innerText, imgs: imgs, anims: anims, resources: resources, figs: figs,
        merror: document.querySelectorAll('mjx-merror, .MathJax_Error').length,
        mjx: document.querySelectorAll('mjx-container').length};
"""


_OVERFLOW = """
const art = document.querySelector('article.bd-article') || document.querySelector('main');
const box = art.getBoundingClientRect(), cs = getComputedStyle(art);
const left = box.left + parseFloat(cs.paddingLeft) - 1, right = box.right - parseFloat(cs.paddingRight) + 1;
const scrolls = el => ['auto', 'scroll'].includes(getComputedStyle(el).overflowX);
const inScroller = el => { for (let p = el.parentElement; p && p !== art; p = p.parentElement) { if (scrolls(p)) return true; } return false; };
const name = el => el.tagName.toLowerCase() + (el.className && typeof el.className === 'string' ? '.' + el.className.trim().split(/\\s+/).join('.') : '')
  + ': ' + (el.textContent || '').trim().replace(/\\s+/g, ' ').slice(0, 60);
const outside = [];
for (const el of art.querySelectorAll('*')) {
  const b = el.getBoundingClientRect();
  if (b.width === 0 || b.height === 0 || getComputedStyle(el).visibility === 'hidden') continue;
  if (el.closest('mjx-assistive-mml')) continue;  // MathJax's invisible copy for screen readers
  if ((b.right > right || b.left < left) && !inScroller(el)) outside.push(name(el) + ` (${Math.round(b.left)}-${Math.round(b.right)} px, column ${Math.round(left)}-${Math.round(right)})`);
}
const code = Array.from(art.querySelectorAll('pre'));
const codeHidden = code.filter(p => p.scrollWidth > p.clientWidth + 1).map(name);
const eqs = Array.from(art.querySelectorAll('mjx-container[display="true"]'));
const wide = [], clipped = [];
for (const e of eqs) {
  const holder = e.parentElement;
  if (Math.max(e.scrollWidth, holder.scrollWidth) <= holder.clientWidth + 1 && e.scrollWidth <= e.clientWidth + 1) continue;
  let tex = '';
  try { tex = MathJax.startup.document.getMathItemsWithin(e)[0].math.trim().replace(/\\s+/g, ' ').slice(0, 70); } catch (err) { tex = name(e); }
  wide.push(tex);
  if (!scrolls(holder) && !scrolls(e)) clipped.push(tex);
}
return {pageScroll: document.documentElement.scrollWidth - document.documentElement.clientWidth,
        outside: outside, code: code.length, codeHidden: codeHidden, equations: eqs.length, wide: wide, clipped: clipped};
"""


def meaningful_alt(alt):
    """An image's text alternative says something: not missing, not a file path, not a few letters."""
    if not isinstance(alt, str):
        return False
    alt = alt.strip()
    return len(alt) >= 15 and "/_images/" not in alt and not alt.lower().endswith((".png", ".svg", ".jpg", ".jpeg", ".gif"))


def _severe_console_errors(drv):
    return [entry["message"] for entry in drv.get_log("browser") if entry.get("level") == "SEVERE"]


def overflow_facts(drv):
    """Horizontal overflow of the loaded page (see the module docstring)."""
    return drv.execute_script(_OVERFLOW)


@pytest.mark.parametrize("page", toc_pages())
def test_page_renders(page, server, driver):
    url = f"{server}/{page}.html"
    with urllib.request.urlopen(url, timeout=30) as resp:
        assert resp.status == 200, f"{url}: HTTP {resp.status}"
    driver.get_log("browser")  # drop messages of earlier pages
    driver.get(url)
    state = driver.execute_async_script(_WAIT_MATHJAX)
    assert state in ("ok", "no-mathjax"), f"{page}: MathJax did not finish ({state})"
    facts = driver.execute_script(_PAGE_FACTS)

    errors = _severe_console_errors(driver)
    assert not errors, f"{page}: JavaScript console errors: {errors}"

    outside = [r for r in facts["resources"] if not r.startswith((server, "data:", "blob:"))]
    assert not outside, f"{page}: fetched from outside the book (must read offline): {outside}"

    assert facts["merror"] == 0, f"{page}: {facts['merror']} TeX errors rendered by MathJax"
    raw = [m for m in re.findall(r"\$\$|\\\(|\\\[|\\begin\{", facts["text"])]
    assert not raw, f"{page}: unrendered TeX left in the page text: {raw[:5]}"

    broken = [i["src"] for i in facts["imgs"] if not i["ok"]]
    assert not broken, f"{page}: images that did not load: {broken}"

    no_alt = [f"{f['src']}: alt={f['alt']!r}" for f in facts["figs"] if not meaningful_alt(f["alt"])]
    assert not no_alt, (f"{page}: {len(no_alt)} of {len(facts['figs'])} images in the text have no text alternative "
                        f"(see _ext/figure_alt.py): {no_alt[:3]}")

    for k, anim in enumerate(facts["anims"]):
        assert anim["controls"] >= 3 and anim["slider"], f"{page}: animation {k} has no controls"
        assert anim["frame"], f"{page}: animation {k} did not draw its first frame"

    chrome = driver.execute_script("""
      const visible = el => el.offsetParent !== null && el.getBoundingClientRect().width > 0;
      return {search: Array.from(document.querySelectorAll('.search-button-field, input[type=search]')).filter(visible).length,
              logo: Array.from(document.querySelectorAll('img.logo__image')).filter(i => visible(i) && i.naturalWidth > 0).length};""")
    assert chrome["search"] == 1, f"{page}: {chrome['search']} search boxes visible (expected one)"
    assert chrome["logo"] >= 1, f"{page}: no logo shown"

    over = overflow_facts(driver)
    assert over["pageScroll"] <= 0, f"{page}: the page scrolls sideways by {over['pageScroll']} px"
    assert not over["outside"], f"{page}: elements outside the text column: {over['outside'][:5]}"
    assert not over["codeHidden"], (f"{page}: {len(over['codeHidden'])} of {over['code']} code blocks hide text "
                                    f"behind a scrollbar: {over['codeHidden'][:3]}")
    assert not over["clipped"], f"{page}: equations clipped: {over['clipped'][:3]}"
    assert not over["wide"], (f"{page}: {len(over['wide'])} of {over['equations']} equations wider than "
                              f"the text column (break them over lines): {over['wide'][:3]}")

    if page in SCREENSHOT_PAGES:
        SHOTS.mkdir(parents=True, exist_ok=True)
        driver.save_screenshot(str(SHOTS / (page.replace("/", "__") + ".png")))


def test_search_finds_particle(server, driver):
    from selenium.webdriver.support.ui import WebDriverWait

    driver.get(f"{server}/search.html?q=particle")
    def _results(d):
        return d.execute_script(
            "return document.querySelectorAll('#search-results li, ul.search li').length;")
    try:
        n = WebDriverWait(driver, 30, poll_frequency=0.25).until(lambda d: _results(d) or False)
    except Exception:
        n = 0
    assert n > 0, "the search page returned no results for 'particle'"
    SHOTS.mkdir(parents=True, exist_ok=True)
    driver.save_screenshot(str(SHOTS / "search_particle.png"))


def test_overflow_check_catches_overflow(server, driver):
    """The overflow check sees a code line hidden behind a scrollbar, a box wider than the column,
    a clipped equation and an equation that scrolls in its box, once they are injected into a
    page that passes it."""
    page = "chapters/01_bayes_filters"
    driver.get(f"{server}/{page}.html")
    assert driver.execute_async_script(_WAIT_MATHJAX) in ("ok", "no-mathjax")
    clean = overflow_facts(driver)
    assert not clean["codeHidden"] and not clean["outside"] and not clean["clipped"] and not clean["wide"], clean
    driver.execute_script("""
      const art = document.querySelector('article.bd-article');
      const pre = document.createElement('pre');
      pre.style.whiteSpace = 'pre'; pre.style.overflowX = 'auto';
      pre.textContent = 'x = 1  # ' + 'a very long comment '.repeat(40);
      art.appendChild(pre);
      const wide = document.createElement('div');
      wide.style.width = '3000px'; wide.textContent = 'wide';
      art.appendChild(wide);
      const [first, second] = document.querySelectorAll('mjx-container[display="true"]');
      const holder = first.parentElement;
      holder.style.overflowX = 'hidden'; holder.style.width = '40px';
      first.style.overflowX = 'hidden';
      second.parentElement.style.overflowX = 'auto'; second.parentElement.style.width = '40px';
    """)
    dirty = overflow_facts(driver)
    assert len(dirty["codeHidden"]) == 1, dirty["codeHidden"]
    assert any(o.startswith("div: wide") for o in dirty["outside"]), dirty["outside"]
    assert len(dirty["clipped"]) == 1, f"a clipped equation was not reported: {dirty['clipped']}"
    assert len(dirty["wide"]) == 2, f"two equations wider than their box, reported: {dirty['wide']}"


@pytest.fixture(scope="module")
def axe_source():
    if not AXE_JS.is_file():
        _missing(f"axe-core not found at {AXE_JS}: npm install --prefix .ci-node axe-core@4 (or set SLAM_AXE_JS)")
    return AXE_JS.read_text(encoding="utf-8")


_AXE_RUN = """
const done = arguments[arguments.length - 1];
axe.run(document, {resultTypes: ['violations']})
  .then(r => done(r.violations.map(v => ({id: v.id, impact: v.impact, help: v.help,
                                          nodes: v.nodes.map(n => n.target.join(' ')).slice(0, 5)}))))
  .catch(e => done([{id: 'axe-error', impact: 'critical', help: String(e), nodes: []}]));
"""


def axe_violations(drv, source, impacts=("serious", "critical")):
    """axe-core's violations of the loaded page with one of ``impacts``."""
    if not drv.execute_script("return typeof window.axe !== 'undefined';"):
        drv.execute_script(source)
    return [v for v in drv.execute_async_script(_AXE_RUN) if v["impact"] in impacts]


def _load(drv, url):
    drv.get(url)
    state = drv.execute_async_script(_WAIT_MATHJAX)
    assert state in ("ok", "no-mathjax"), f"{url}: MathJax did not finish ({state})"


@pytest.mark.parametrize("page", toc_pages())
def test_page_accessible(page, server, driver, axe_source):
    _load(driver, f"{server}/{page}.html")
    bad = axe_violations(driver, axe_source)
    assert not bad, f"{page}: axe-core reports serious or critical violations: " + "; ".join(
        f"{v['id']} ({v['impact']}: {v['help']}) at {v['nodes']}" for v in bad)


def test_axe_check_catches_violations(server, driver, axe_source):
    """The accessibility check sees an image without alt text and an unlabelled input, once they are
    injected into a page that passes it."""
    _load(driver, f"{server}/chapters/01_bayes_filters.html")
    assert axe_violations(driver, axe_source) == []
    driver.execute_script("""
      const art = document.querySelector('article.bd-article');
      const img = document.createElement('img'); img.src = art.querySelector('img') ? art.querySelector('img').src : '';
      art.appendChild(img);
      const inp = document.createElement('input'); inp.type = 'text'; art.appendChild(inp);
    """)
    ids = {v["id"] for v in axe_violations(driver, axe_source)}
    assert {"image-alt", "label"} <= ids, ids


def test_pdf_holds_every_chapter_and_figure():
    """The PDF of the whole book (tools/book_pdf.py over the singlehtml build)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("book_pdf", ROOT / "tools" / "book_pdf.py")
    book_pdf = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(book_pdf)
    try:
        book_pdf.single_page(SINGLE)
    except FileNotFoundError:
        _missing("no single-page build: run  jupyter-book build . --builder singlehtml  first")
    out = ROOT / "_build" / "pdf" / "book.pdf"
    info = book_pdf.print_pdf(SINGLE, out)
    facts = book_pdf.check_pdf(out, SINGLE)
    assert facts["missing_titles"] == [], f"chapters missing from the PDF: {facts['missing_titles']}"
    assert facts["figures"] > 20, f"the single page holds only {facts['figures']} figures"
    assert facts["images"] >= facts["figures"], (
        f"the PDF holds {facts['images']} images for the book's {facts['figures']} figures")
    assert info["images"] >= facts["figures"]
