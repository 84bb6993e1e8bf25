"""The browser viewer measured: the page in headless Chromium flying the 1M-triangle
terrain through `caveclod serve --web-port`, one configuration after another.

For each configuration (cameras x frame encoding) the page flies the flyover
at 30 Hz for ``--seconds`` at 1280x720 (each camera refined for its
quadrant); after a warm-up (refining up from the base mesh) the script reads
``window.caveclodStats`` twice and reports, over the interval between:
frames/s, bytes per frame, the page's time applying a frame (decoding,
patching, CRC-32 checks; not drawing), the server's CPU per frame, faces
drawn, and over the whole run pose -> frame latency p50/p99 as the page
measures it, divergences and keyframe requests. WebGL2 runs on SwiftShader
(the CPU) here, so the drawing's frame rate says nothing about a GPU; the
protocol's figures do.

    .venv/bin/python benchmarks/web.py [--size 708] [--seconds 20]

Writes benchmarks/results/web.json and web.png. Needs Debian's
chromium-headless-shell and Playwright (`make test` installs Playwright).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from service import RESULTS, Server, cpu_seconds, mesh_path  # noqa: E402

BROWSER = "chromium-headless-shell"
BROWSER_ARGS = ["--no-sandbox", "--enable-unsafe-swiftshader", "--use-angle=swiftshader"]
CONFIGS = [(1, "ops"), (1, "raw"), (4, "ops"), (4, "raw")]


def run_config(browser, base: str, server_pid: int, cameras: int, encoding: str, seconds: float,
               warmup: float) -> dict:
    page = browser.new_page(viewport={"width": 1280, "height": 720})
    errors: list[str] = []
    page.on("console", lambda m: m.type == "error" and errors.append(m.text))
    try:
        # Geomorphs off (the page's default is on): these figures are the protocol's and the page's frame path.
        page.goto(f"{base}?trajectory=flyover&cameras={cameras}&encoding={encoding}&morph=0")
        deadline = time.monotonic() + 60
        while not page.evaluate("window.caveclodStats.frames") and time.monotonic() < deadline:
            time.sleep(0.1)
        time.sleep(warmup)
        a, cpu_a, t_a = page.evaluate("window.caveclodStats"), cpu_seconds(server_pid), time.monotonic()
        time.sleep(seconds - warmup)
        b, cpu_b, t_b = page.evaluate("window.caveclodStats"), cpu_seconds(server_pid), time.monotonic()
    finally:
        page.close()
    frames = max(b["frames"] - a["frames"], 1)
    return {
        "cameras": cameras, "encoding": encoding, "frames_per_s": round(frames / (t_b - t_a), 1),
        "bytes_per_frame": round((b["frameBytes"] - a["frameBytes"]) / frames, 1),
        "page_apply_ms_per_frame": round((b["applyMs"] - a["applyMs"]) / frames, 3),
        "server_cpu_ms_per_frame": round(1000 * (cpu_b - cpu_a) / frames, 3),
        "faces_drawn": b["facesDrawn"], "latency_ms_p50": round(b["latencyMsP50"], 1),
        "latency_ms_p99": round(b["latencyMsP99"], 1), "draw_fps": round(b["fps"], 1),
        "divergences": b["divergences"], "crc_checks": b["crcChecks"], "keyframe_requests": b["keyframeRequests"],
        "bad_frames": b["badFrames"], "error": b["error"], "console_errors": errors[:5],
    }


def plot(rows: list, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    labels = [f"{r['cameras']} cam, {r['encoding']}" for r in rows]
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6))
    for ax, key, title in zip(axes, ("bytes_per_frame", "page_apply_ms_per_frame", "server_cpu_ms_per_frame"),
                              ("bytes per frame", "page: ms applying a frame", "server: CPU ms per frame")):
        ax.bar(labels, [r[key] for r in rows], color=["#4c72b0", "#dd8452"] * 2)
        ax.set_title(title)
        ax.tick_params(axis="x", labelrotation=30)
    fig.suptitle("browser viewer, flyover of the 1M-triangle terrain at 30 Hz (headless Chromium)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=708, help="default terrain size (708: about 1M triangles)")
    ap.add_argument("--seconds", type=float, default=20.0, help="flight per configuration (default 20)")
    ap.add_argument("--warmup", type=float, default=4.0, help="seconds left out at the start (default 4)")
    args = ap.parse_args()
    if args.seconds <= args.warmup:
        ap.error("--seconds must exceed --warmup")
    executable = shutil.which(BROWSER)
    if executable is None:
        print(f"{BROWSER} is not installed (apt-get install {BROWSER})", file=sys.stderr)
        return 2
    from playwright.sync_api import sync_playwright
    mesh = mesh_path(args.size)
    server = Server(mesh, "--web-port", "0")
    try:
        base = server.proc.stdout.readline().split()[-1]           # "viewer on http://127.0.0.1:P/"
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=executable, args=BROWSER_ARGS)
            try:
                rows = []
                for cameras, encoding in CONFIGS:
                    row = run_config(browser, base, server.proc.pid, cameras, encoding, args.seconds, args.warmup)
                    print(json.dumps(row), flush=True)
                    rows.append(row)
            finally:
                browser.close()
    finally:
        server.stop()
    RESULTS.mkdir(parents=True, exist_ok=True)
    out = {"mesh": mesh.name, "seconds": args.seconds, "warmup": args.warmup, "viewport": [1280, 720],
           "rate_hz": 30, "trajectory": "flyover", "rows": rows}
    (RESULTS / "web.json").write_text(json.dumps(out, indent=2) + "\n")
    plot(rows, RESULTS / "web.png")
    bad = [r for r in rows if r["divergences"] or r["error"] or r["console_errors"]]
    print(f"wrote {RESULTS / 'web.json'} and web.png" + (f"; {len(bad)} configurations had errors" if bad else ""))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
