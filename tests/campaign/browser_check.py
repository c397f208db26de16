"""The campaign report as people see it (test_report_browser.py): report.html opened in headless Chromium
(Debian's `chromium`, scripts/ensure_chromium.sh), without a driver (no Playwright, no WebSocket): two runs
of the browser itself.

1. `--dump-dom` of a copy of the page with a probe script put first in <head>: it records console.error /
   console.warn calls, uncaught errors and resource load errors (an image that does not decode), and once
   the page has loaded (`--virtual-time-budget` lets it) writes, into a <pre> at the end of the body, for
   every <img>: whether it decoded (naturalWidth/Height) and is visible (laid out with a size, not hidden).
2. `--screenshot` of the page itself; the PNG must not be blank (most of it one colour).

Every run gets a new empty --user-data-dir and the flags that keep Chromium off the network and quiet:
--headless --no-sandbox --disable-gpu --disable-quic --no-first-run --disable-background-networking
--disable-component-update --disable-sync. `chromium_problem()` says why Chromium cannot start here (the
test skips with that reason, nowhere else).
"""

from __future__ import annotations

import html
import json
import shutil
import subprocess
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync")
BROWSERS = ("chromium", "chromium-browser", "google-chrome")
PROBE_ID = "uwb-hil-probe"
TIMEOUT_S = 90.0
WINDOW = (1280, 2400)
#: a screenshot is blank when this share of its pixels or more has the most common colour
BLANK_SHARE = 0.995

_PROBE = """<script>(function(){
var errors=[];
function note(kind,args){errors.push(kind+": "+Array.prototype.map.call(args,String).join(" ").slice(0,300));}
var ce=console.error, cw=console.warn;
console.error=function(){note("console.error",arguments);return ce.apply(console,arguments);};
console.warn=function(){note("console.warn",arguments);return cw.apply(console,arguments);};
window.addEventListener("error",function(e){var t=e.target;
  if(t&&t!==window&&t.tagName){note("resource error",[t.tagName+" "+(t.alt||t.src||"").slice(0,80)]);}
  else{note("uncaught",[e.message]);}},true);
window.addEventListener("unhandledrejection",function(e){note("unhandled rejection",[e.reason]);});
window.addEventListener("load",function(){
  var imgs=Array.prototype.map.call(document.images,function(i){var r=i.getBoundingClientRect(),
    s=getComputedStyle(i);return {alt:i.alt.slice(0,80),complete:i.complete,natural_w:i.naturalWidth,
    natural_h:i.naturalHeight,w:r.width,h:r.height,visible:s.display!=="none"&&s.visibility!=="hidden"&&
    parseFloat(s.opacity)>0&&r.width>0&&r.height>0};});
  var pre=document.createElement("pre");pre.id="%s";
  pre.textContent=JSON.stringify({errors:errors,images:imgs});document.body.appendChild(pre);});
})();</script>""" % PROBE_ID


@dataclass
class BrowserCheck:
    """What the browser saw; `problems()` lists what fails the check (empty: the page is fine)."""

    console_errors: list[str] = field(default_factory=list)
    images: list[dict[str, Any]] = field(default_factory=list)
    screenshot: Path | None = None
    blank_share: float = 1.0

    def problems(self) -> list[str]:
        out = list(self.console_errors)
        for k, img in enumerate(self.images):
            if not (img.get("complete") and img.get("natural_w", 0) > 0 and img.get("natural_h", 0) > 0):
                out.append(f"figure {k + 1} ({img.get('alt')!r}) does not decode")
            elif not img.get("visible"):
                out.append(f"figure {k + 1} ({img.get('alt')!r}) is not visible")
        if self.blank_share >= BLANK_SHARE:
            out.append(f"the screenshot is blank ({100 * self.blank_share:.1f} % one colour)")
        return out


def find_chromium() -> str | None:
    return next((b for b in (shutil.which(n) for n in BROWSERS) if b), None)


def _run(browser: str, args: list[str], timeout_s: float) -> subprocess.CompletedProcess[str]:
    with tempfile.TemporaryDirectory(prefix="uwb-hil-chromium-") as profile:   # a new empty profile
        return subprocess.run([browser, *FLAGS, f"--user-data-dir={profile}", *args], capture_output=True,
                              text=True, timeout=timeout_s)


def chromium_problem(timeout_s: float = 60.0) -> str | None:
    """Why headless Chromium cannot start here (None when it can): not installed, or it fails on a blank page."""
    browser = find_chromium()
    if browser is None:
        return f"no Chromium on PATH ({', '.join(BROWSERS)}): scripts/ensure_chromium.sh installs Debian's chromium"
    try:
        proc = _run(browser, ["--dump-dom", "about:blank"], timeout_s)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return f"{browser} cannot start: {exc}"
    if proc.returncode != 0 or "<html" not in proc.stdout:
        return f"{browser} cannot start (exit {proc.returncode}): {proc.stderr.strip()[-300:]}"
    return None


def probe_page(page: Path, work: Path, browser: str, timeout_s: float = TIMEOUT_S) -> dict[str, Any]:
    """Errors and images of `page` as the probe script records them (a copy of the page in `work`)."""
    text = page.read_text(encoding="utf-8")
    head = text.find("<head>")
    probed = text[:head + 6] + _PROBE + text[head + 6:] if head >= 0 else _PROBE + text
    copy = work / "probe.html"
    copy.write_text(probed, encoding="utf-8")
    proc = _run(browser, ["--virtual-time-budget=10000", "--dump-dom", copy.resolve().as_uri()], timeout_s)
    start = proc.stdout.find(f'<pre id="{PROBE_ID}">')
    if start < 0:
        return {"errors": [f"the probe did not run (exit {proc.returncode}): {proc.stderr.strip()[-300:]}"],
                "images": []}
    body = proc.stdout[start + len(f'<pre id="{PROBE_ID}">'):proc.stdout.index("</pre>", start)]
    return dict(json.loads(html.unescape(body)))


def blank_share(png: Path) -> float:
    """Share of the screenshot's pixels that have its most common colour."""
    import matplotlib.image as mpimg
    img = np.asarray(mpimg.imread(png))
    rgb = (img[..., :3] * 255).astype(np.uint8).reshape(-1, 3) if img.dtype.kind == "f" else img[..., :3].reshape(-1, 3)
    _, counts = np.unique(rgb, axis=0, return_counts=True)
    return float(counts.max() / counts.sum())


def check_report(page: Path, work: Path, timeout_s: float = TIMEOUT_S) -> BrowserCheck:
    """Open `page` in headless Chromium: console errors, every figure decoded and visible, a screenshot
    (work/screenshot.png) that is not blank. RuntimeError when there is no Chromium (chromium_problem)."""
    browser = find_chromium()
    if browser is None:
        raise RuntimeError(chromium_problem() or "no Chromium")
    work.mkdir(parents=True, exist_ok=True)
    probe = probe_page(page, work, browser, timeout_s)
    shot = work / "screenshot.png"
    _run(browser, [f"--screenshot={shot.resolve()}", f"--window-size={WINDOW[0]},{WINDOW[1]}",
                   "--hide-scrollbars", page.resolve().as_uri()], timeout_s)
    if not shot.is_file():
        return BrowserCheck(console_errors=["no screenshot was written"], images=probe["images"])
    return BrowserCheck(console_errors=[str(e) for e in probe["errors"]], images=probe["images"], screenshot=shot,
                        blank_share=blank_share(shot))
