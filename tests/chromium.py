"""Screenshots of a page in headless Chromium, driven over the DevTools protocol (CDP).

Chromium's own `--screenshot` flag captures the page as soon as it has loaded, before a
WebAssembly app (Rerun's web viewer) has downloaded, compiled and drawn anything. Here the page
is kept open and captured every `interval` seconds until two captures in a row are the same
and differ from the first one (the loading screen), or until `timeout`.
"""

import base64
import json
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
import urllib.request

# The flags this machine's Chromium needs (/work/.library/env/machines/python.md, "Known to work"),
# with SwiftShader's software WebGL instead of a GPU.
FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
]


def chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for_http(url: str, timeout: float) -> None:
    deadline = time.time() + timeout
    while True:
        try:
            urllib.request.urlopen(url, timeout=2).read()
            return
        except OSError:
            if time.time() > deadline:
                raise
            time.sleep(0.2)


class _Page:
    def __init__(self, ws_url: str) -> None:
        from websockets.sync.client import connect

        self.ws = connect(ws_url, max_size=None, open_timeout=30)
        self.next_id = 0

    def call(self, method: str, **params):
        self.next_id += 1
        self.ws.send(json.dumps({"id": self.next_id, "method": method, "params": params}))
        while True:
            message = json.loads(self.ws.recv(timeout=60))
            if message.get("id") == self.next_id:
                if "error" in message:
                    raise RuntimeError(f"{method}: {message['error']}")
                return message["result"]

    def close(self) -> None:
        self.ws.close()


def screenshot(url: str, out: str, width: int = 1600, height: int = 900, timeout: float = 180, interval: float = 3):
    """Saves a PNG of `url` once it has stopped changing; returns the seconds it took."""
    port = free_port()
    profile = tempfile.mkdtemp(prefix="vnl-chromium-")
    proc = subprocess.Popen(
        [
            chromium(),
            *FLAGS,
            f"--remote-debugging-port={port}",
            f"--user-data-dir={profile}",
            f"--window-size={width},{height}",
            "about:blank",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,  # its renderer and GPU processes are ended with it
    )
    t0 = time.time()
    try:
        wait_for_http(f"http://127.0.0.1:{port}/json/version", 30)
        targets = json.loads(urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list").read())
        page = _Page(next(t for t in targets if t["type"] == "page")["webSocketDebuggerUrl"])
        try:
            page.call(
                "Emulation.setDeviceMetricsOverride", width=width, height=height, deviceScaleFactor=1, mobile=False
            )
            page.call("Page.navigate", url=url)
            first = previous = None
            while time.time() - t0 < timeout:
                time.sleep(interval)
                shot = base64.b64decode(page.call("Page.captureScreenshot", format="png")["data"])
                first = first or shot
                if shot == previous and shot != first:
                    break
                previous = shot
            with open(out, "wb") as f:
                f.write(previous)
        finally:
            page.close()
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=30)
        shutil.rmtree(profile, ignore_errors=True)
    return time.time() - t0
