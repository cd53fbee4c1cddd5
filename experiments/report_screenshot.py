"""Open a comparison report in a real headless browser, offline, and check that its 3-D view renders.

    python experiments/report_screenshot.py DIR/report.html [--out shot.png] [--chromium chromium]

Needs Chromium (Debian: ``apt-get install -y chromium``); not part of the test suite. Network
access is cut (every host name resolves to nothing, no background networking, a fresh profile),
so the page must work from the file alone. Checks, in the rendered page:
- the plot's script finished (``data-rendered="yes"`` on the 3-D view's div) and drew a canvas;
- in a screenshot of the top of the page (the 3-D view comes right after the title), pixels of each
  estimator's trajectory colour: a blank or failed WebGL canvas has none.
Prints what it found and exits 1 if a check fails. Look at the screenshot as well.
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--enable-unsafe-swiftshader",  # software WebGL (plotly's 3-D scenes) without a GPU
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
    "--disable-sync",
    "--host-resolver-rules=MAP * ~NOTFOUND",  # offline: no host name resolves
    "--virtual-time-budget=30000",  # let the page unpack plotly.js and draw before the capture
]
# The interactive view's trace colours (semslam.eval.interactive.COLORS) as RGB.
COLORS = {"dr": (214, 39, 40), "ekf": (31, 119, 180), "graph": (44, 160, 44)}


def chromium(binary: str, page: Path, profile: Path, *extra: str) -> subprocess.CompletedProcess:
    cmd = [binary, *FLAGS, f"--user-data-dir={profile}", *extra, page.resolve().as_uri()]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=300)


def external_loads(html: str) -> list[str]:
    """Resources the page would fetch from the network (script, link, img, iframe sources)."""
    return re.findall(r"<(?:script|link|img|iframe)[^>]+(?:src|href)=[\"']?(https?://[^\"' >]+)", html)


def colour_pixels(png: Path, tolerance: int = 40) -> dict[str, int]:
    import matplotlib.image as mpimg

    img = mpimg.imread(png)[..., :3]
    rgb = (img * 255).astype(int) if img.dtype != np.uint8 else img.astype(int)
    return {name: int(np.sum(np.all(np.abs(rgb - c) <= tolerance, axis=-1))) for name, c in COLORS.items()}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("report", type=Path)
    ap.add_argument("--out", type=Path, default=Path("report_3d.png"))
    ap.add_argument("--chromium", default=shutil.which("chromium") or "chromium")
    ap.add_argument("--size", default="1280,1100", help="window size of the screenshot (the top of the page)")
    args = ap.parse_args()
    ok = True
    loads = external_loads(args.report.read_text())
    print(f"network resources the page would load: {loads or 'none'}")
    ok &= not loads
    with tempfile.TemporaryDirectory() as profile:
        dom = chromium(args.chromium, args.report, Path(profile) / "dom", "--dump-dom").stdout
        chromium(
            args.chromium, args.report, Path(profile) / "shot", f"--window-size={args.size}", f"--screenshot={args.out}"
        )
    rendered = 'data-rendered="yes"' in dom
    canvases = len(re.findall(r"<canvas\b", dom))
    failed = re.search(r'<div id="semslam-3d"[^>]*>([^<]*could not be drawn[^<]*)', dom)
    print(f"3-D view rendered: {rendered}; canvases in the page: {canvases}")
    if failed:
        print(f"the page says: {failed.group(1)}")
    ok &= rendered and canvases > 0 and not failed
    if not args.out.is_file():
        print("no screenshot was written")
        return 1
    pixels = colour_pixels(args.out)
    print(f"screenshot {args.out}: pixels of each trajectory colour {pixels}")
    ok &= all(n > 0 for name, n in pixels.items() if name != "dr")  # dr's map starts hidden; its line is thin
    print("OK" if ok else "FAILED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
