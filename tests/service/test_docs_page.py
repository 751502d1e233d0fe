"""The service's API page (/docs) on a closed network: its script and style come from the package
(`swagger_ui_bundle`), never from a CDN, and a real headless Chromium, with every address but
127.0.0.1 unreachable, renders every operation of the API from them.

Skipped only where no Chromium binary exists (`.ci/run` installs Debian's `chromium`)."""

from __future__ import annotations

import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

httpx = pytest.importorskip("httpx")
pytest.importorskip("fastapi")
pytest.importorskip("swagger_ui_bundle")

pytestmark = pytest.mark.slow

HOST = "127.0.0.1"
START_S = 90.0  # a server start imports torch and FastAPI: seconds on a loaded 2-core machine
BROWSERS = ("chromium", "chromium-browser", "google-chrome")
# Network off for the browser: every host name but 127.0.0.1 resolves to nothing, and whatever is
# not loopback goes to a proxy on a closed port.
OFFLINE = ["--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1", "--proxy-server=http://127.0.0.1:9"]


def browser() -> str | None:
    return next((path for path in map(shutil.which, BROWSERS) if path), None)


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    root = tmp_path_factory.mktemp("docs") / "root"
    with socket.socket() as s:
        s.bind((HOST, 0))
        port = s.getsockname()[1]
    log = root.parent / "serve.log"
    command = [sys.executable, "-m", "nerfaug.cli", "serve", "--root", str(root), "--host", HOST]
    command += ["--port", str(port), "--device", "cpu"]
    with open(log, "wb") as out:
        process = subprocess.Popen(command, stdout=out, stderr=subprocess.STDOUT)
    url = f"http://{HOST}:{port}"
    try:
        deadline = time.monotonic() + START_S
        while True:
            assert process.poll() is None, log.read_text()[-2000:]
            try:
                if httpx.get(f"{url}/health").status_code == 200:
                    break
            except httpx.TransportError:
                pass
            assert time.monotonic() < deadline, f"no answer within {START_S} s: {log.read_text()[-2000:]}"
            time.sleep(0.1)
        yield url
    finally:
        process.send_signal(signal.SIGKILL)
        process.wait(30)


def test_the_docs_page_loads_nothing_from_another_host(server):
    page = httpx.get(f"{server}/docs")
    assert page.status_code == 200
    assets = re.findall(r"""(?:src|href)=["']([^"']+)["']""", page.text)
    assert any(a.endswith("swagger-ui-bundle.js") for a in assets) and any(a.endswith(".css") for a in assets)
    assert all(a.startswith("/") and not a.startswith("//") for a in assets), assets
    for asset in assets:
        assert httpx.get(f"{server}{asset}").status_code == 200, asset
    assert httpx.get(f"{server}/redoc").status_code == 404  # ReDoc's page would need a CDN


@pytest.mark.skipif(browser() is None, reason=f"no Chromium binary ({', '.join(BROWSERS)}) on PATH")
def test_headless_chromium_offline_renders_every_operation(server, tmp_path):
    spec = httpx.get(f"{server}/openapi.json").json()
    operations = {
        (path, op["summary"]) for path, methods in spec["paths"].items() for op in methods.values() if "summary" in op
    }
    assert len(operations) >= 10
    command = [browser(), "--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", *OFFLINE]
    command += [f"--user-data-dir={tmp_path / 'profile'}", "--virtual-time-budget=20000", "--dump-dom"]
    env = {**os.environ, "HOME": str(tmp_path)}
    done = subprocess.run([*command, f"{server}/docs"], capture_output=True, text=True, timeout=180, env=env)
    dom = done.stdout
    assert "swagger-ui" in dom, done.stderr[-2000:]
    rendered = set(re.findall(r'class="opblock-summary-path" data-path="([^"]+)"', dom))
    missing = {path for path, _ in operations} - rendered
    assert not missing, f"operations not rendered: {missing}"
    for _, summary in operations:
        assert summary in dom, summary
    assert "Failed to load API definition" not in dom and "Unable to render this definition" not in dom


def test_the_test_finds_chromium_where_ci_installs_it():
    """.ci/run installs Debian's chromium when it is missing: the browser test above runs in CI."""
    ci = (Path(__file__).resolve().parents[2] / ".ci" / "run").read_text()
    assert "apt-get install" in ci and "chromium" in ci and "command -v chromium" in ci
