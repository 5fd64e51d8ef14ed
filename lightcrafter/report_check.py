"""Open the run report in headless Chromium and check that every image and video on it loads.

    python -m lightcrafter.report_check results/report/index.html [--screenshot report.png]

A harness page next to the report loads it in an iframe (same folder, ``--allow-file-access-from-
files``), waits for every ``<img>`` to finish and every ``<video>`` to read its metadata (or fail), and
writes a JSON verdict into its own DOM, which ``--dump-dom`` prints. A video counts as loaded when the
browser decoded its header (``readyState >= 1`` and a non-zero ``videoWidth``): an mp4 the browser
cannot play (codec, truncated file) fails here although the file exists. The harness is written under
a temporary name and removed afterwards.
"""

from __future__ import annotations

import argparse
import html
import json
import re
import shutil
import subprocess
import sys
import tempfile
import uuid
from pathlib import Path

BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")

_HARNESS = """<!doctype html><html><body><pre id="verdict">pending</pre>
<iframe id="f" src="{page}" style="width:1300px;height:900px"></iframe>
<script>
const f = document.getElementById("f");
const wait = (p, ms) => Promise.race([p, new Promise(r => setTimeout(r, ms))]);
f.onload = async () => {{
  const d = f.contentDocument;
  if (!d) {{ document.getElementById("verdict").textContent = JSON.stringify({{error: "report not readable"}}); return; }}
  const imgs = [...d.images];
  await wait(Promise.all(imgs.map(i => i.complete ? 0 : new Promise(r => {{ i.onload = i.onerror = r; }}))), 15000);
  const vids = [...d.querySelectorAll("video")];
  await wait(Promise.all(vids.map(v => (v.readyState >= 1 || v.error) ? 0 :
      new Promise(r => {{ v.onloadedmetadata = v.onerror = r; v.preload = "metadata"; v.load(); }}))), 15000);
  const out = {{
    title: d.title, text_chars: d.body ? d.body.innerText.length : 0,
    images: imgs.length, broken_images: imgs.filter(i => !i.complete || i.naturalWidth === 0)
        .map(i => i.getAttribute("src")),
    videos: vids.length, broken_videos: vids.filter(v => v.error || v.readyState < 1 || v.videoWidth === 0)
        .map(v => v.getAttribute("src") || (v.querySelector("source") || {{}}).src),
    video_sizes: vids.map(v => [v.videoWidth, v.videoHeight]),
  }};
  document.getElementById("verdict").textContent = JSON.stringify(out);
}};
</script></body></html>
"""


def find_browser() -> str | None:
    for name in BROWSERS:
        path = shutil.which(name)
        if path:
            return path
    return None


def _flags(browser: str, profile: str) -> list[str]:
    """``profile``: a fresh user-data folder, so that two checks at once (two test workers, two runs) never
    share Chromium's profile lock."""
    return [browser, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--mute-audio",
            f"--user-data-dir={profile}", "--allow-file-access-from-files",
            "--autoplay-policy=no-user-gesture-required"]


def check_report(index: str | Path, *, browser: str | None = None, timeout_s: float = 120,
                 screenshot: str | Path | None = None) -> dict:
    """Load ``index`` in headless Chromium; returns {title, text_chars, images, broken_images, videos,
    broken_videos, video_sizes[, screenshot]}. Raises RuntimeError when no browser is installed or the
    page never reports."""
    index = Path(index).resolve()
    if not index.is_file():
        raise FileNotFoundError(f"{index}: no report; build it with `snakemake run_report`")
    browser = browser or find_browser()
    if browser is None:
        raise RuntimeError("no Chromium found (apt-get install chromium)")
    harness = index.parent / f".check_{uuid.uuid4().hex[:8]}.html"
    harness.write_text(_HARNESS.format(page=index.name))
    with tempfile.TemporaryDirectory(prefix="report-check-") as profile:
        try:
            r = subprocess.run(_flags(browser, profile) + ["--virtual-time-budget=30000", "--dump-dom",
                                                           harness.as_uri()],
                               capture_output=True, text=True, timeout=timeout_s)
        finally:
            harness.unlink(missing_ok=True)
        m = re.search(r'<pre id="verdict">(.*?)</pre>', r.stdout, re.S)
        if not m or m.group(1).strip() == "pending":
            raise RuntimeError(f"{index}: the browser never reported (exit {r.returncode}): {r.stderr[-500:]}")
        verdict = json.loads(html.unescape(m.group(1)))
        if screenshot:
            subprocess.run(_flags(browser, profile) + [f"--screenshot={Path(screenshot).resolve()}",
                                                       "--window-size=1300,6000", "--virtual-time-budget=10000",
                                                       index.as_uri()],
                           capture_output=True, timeout=timeout_s)
            verdict["screenshot"] = str(screenshot)
    return verdict


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("index", nargs="?", default="results/report/index.html")
    ap.add_argument("--screenshot", default=None)
    a = ap.parse_args(argv)
    try:
        v = check_report(a.index, screenshot=a.screenshot)
    except (RuntimeError, FileNotFoundError) as exc:
        print(f"report_check: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(v, indent=1))
    bad = v.get("error") or v["broken_images"] or v["broken_videos"]
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
