"""What the real-browser tests share: Debian's chromium, a free port, waiting for a server, the
requests a page makes to other machines, and a screenshot's pixels.  (Not a test module.)"""

from __future__ import annotations

import io
import os
import re
import shutil
import socket
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
ARTIFACTS = ROOT / "test-artifacts"
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
needs_chromium = pytest.mark.skipif(
    not os.path.exists(CHROMIUM), reason=f"chromium not found at {CHROMIUM}: run `make browser` (apt) to install it"
)
LOCAL = re.compile(r"(https?|wss?)://(127\.0\.0\.1|localhost)[:/]")


def free_port() -> int:
    """A TCP port nobody listens on now (the servers under test pick no fixed port)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for_port(proc: subprocess.Popen, port: int, what: str, log: Path, timeout: float = 60.0) -> None:
    """Wait until ``proc`` listens on ``port``; fail (naming ``what`` and its log) if it exits or times out."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return
        except OSError:
            if proc.poll() is not None or time.monotonic() > deadline:
                pytest.fail(f"{what} did not start (exit {proc.poll()}); see {log}")
            time.sleep(0.2)


def record_external(page, external: list[str]) -> None:
    """Append to ``external`` every URL ``page`` requests from anywhere but this machine."""

    def seen(request) -> None:
        if not LOCAL.match(request.url) and not request.url.startswith(("data:", "blob:")):
            external.append(request.url)

    page.on("request", seen)


def pixels(png: bytes) -> np.ndarray:
    """A PNG screenshot as (H, W, 3) int16 RGB (differences do not wrap around)."""
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.int16)
