"""droid-web's HTTP/WebSocket side: JSON APIs, read-only, refusals (no browser: see test_web_browser.py)."""
from __future__ import annotations

import asyncio
import subprocess
import sys
import urllib.error
import urllib.request

import pytest

from tests.brain.cellutil import ROOT, free_port, in_process
from tests.observe.webutil import WebServer, lockstep_recording, taken_port


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    return lockstep_recording(tmp_path_factory.mktemp("web") / "trial.mcap")


def test_file_api(recording):
    with WebServer("--file", recording) as w:
        cell = w.get("api/cell")
        assert cell["source"] == "file" and cell["recording_source"] == "lockstep"
        assert {s["name"] for s in cell["subunits"]} == {"arm1", "gmf1", "mvs", "tool"}
        n = cell["file"]["count"]
        assert n > 60
        st = w.get("api/status")
        assert set(st) == {"arm1", "gmf1", "mvs", "tool"}
        assert all(isinstance(v["tick"], int) and v["subunit"] == k for k, v in st.items())
        f0, f1 = w.get("api/frame?i=0"), w.get(f"api/frame?i={n - 1}")
        assert f1["tick"] > f0["tick"] and f1["index"] == n - 1
        assert len(f1["geo"]["links"]["arm1"]) == 7  # base + six link frames
        assert {"tool", "sensor", "workpiece", "arm1/wcp"} <= set(f1["geo"]["frames"])
        assert len(f1["seam"]) >= len(f0["seam"])
        # the status follows the slider
        assert w.get("api/status")["arm1"]["tick"] == f1["subunits"]["arm1"]["tick"]
        # read-only: no method but GET
        req = urllib.request.Request(w.url + "api/status", method="POST", data=b"{}")
        with pytest.raises(urllib.error.HTTPError) as e:
            urllib.request.urlopen(req, timeout=5)
        assert e.value.code == 405
        # vendored three.js with its licence, served locally
        with urllib.request.urlopen(w.url + "static/vendor/three/LICENSE", timeout=5) as r:
            assert b"MIT" in r.read()
        with urllib.request.urlopen(w.url, timeout=5) as r:
            page = r.read().decode()
        assert "importmap" in page and "http" not in page.split("importmap")[1].split("</script>")[0]


def test_websocket_input_is_ignored_and_counted(recording):
    import aiohttp

    async def talk(url):
        async with aiohttp.ClientSession() as s:
            async with s.ws_connect(url + "ws") as ws:
                hello = await ws.receive_json(timeout=5)
                assert hello["type"] == "hello"
                for m in ("hello", '{"cmd": "move"}', "x" * 3000):
                    await ws.send_str(m)
                await ws.send_bytes(b"\x00\xff")
                await asyncio.sleep(0.3)
            async with s.ws_connect(url + "ws") as ws:  # an oversized message: that socket closes
                await ws.receive_json(timeout=5)
                await ws.send_str("y" * 10000)
                msg = await ws.receive(timeout=5)
                assert msg.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED, aiohttp.WSMsgType.CLOSING)

    with WebServer("--file", recording) as w:
        asyncio.run(talk(w.url))
        assert w.get("api/cell")["ws_ignored"] == 5
        assert w.proc.poll() is None


def test_token(recording):
    with WebServer("--file", recording, "--token", "s3cret-token") as w:
        with pytest.raises(urllib.error.HTTPError) as e:
            urllib.request.urlopen(w.url + "api/status", timeout=5)
        assert e.value.code == 401
        assert "arm1" in w.get("api/status", token="s3cret-token")
        with urllib.request.urlopen(w.url, timeout=5) as r:  # the page itself is public code
            assert r.status == 200


def run_web(*args):
    return subprocess.run([sys.executable, "-m", "droid.observe.web", *args], capture_output=True, text=True,
                          cwd=ROOT, timeout=60)


def test_refusals(recording, tmp_path, capsys):
    import droid.observe.web as web

    # refused before anything is started: main() in-process (the port in use: the program)
    out = in_process(web.main, capsys, "--bind", "0.0.0.0", "--file", recording)
    assert out.returncode == 2 and "not loopback" in out.stderr and "--token" in out.stderr
    out = in_process(web.main, capsys, "--file", str(tmp_path / "none.mcap"))
    assert out.returncode == 2 and "no such file" in out.stderr
    out = in_process(web.main, capsys, "--port", "70000")
    assert out.returncode == 2
    with taken_port() as port:
        out = run_web("--port", str(port), "--file", recording)
    assert out.returncode == 1 and f"port {port}" in out.stderr and len(out.stderr.strip().splitlines()) == 1


def test_live_cell_not_up(tmp_path, cell_name):
    from tests.brain.cellutil import make_cell_file

    out = run_web("--cell", str(make_cell_file(tmp_path, cell_name)), "--port", str(free_port()))
    assert out.returncode == 1 and "does not exist" in out.stderr


def test_package_data_ships_every_static_file():
    """pyproject's package-data globs cover every file of droid/observe/static (checked against a built wheel
    by hand: `pip wheel . --no-deps`)."""
    import tomllib
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    globs = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]["droid.observe"]
    pkg = root / "droid" / "observe"
    shipped = {p for g in globs for p in pkg.glob(g) if p.is_file()}
    static = {p for p in (pkg / "static").rglob("*") if p.is_file() and "__pycache__" not in p.parts}
    assert static and static == shipped, sorted(map(str, static - shipped))
    assert (pkg / "static" / "vendor" / "three" / "LICENSE").read_text().startswith("The MIT License")
