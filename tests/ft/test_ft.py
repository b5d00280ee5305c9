"""The ft6 class, the RDT driver and droid-ft's core, without the twin (docs/ft.md).

A scripted "device" here is a plain UDP socket on 127.0.0.1 that sends hand-made records;
the calibration page is a small HTTP server on 127.0.0.1.  Everything is stepped by the
test with its own clock: no verdict depends on timing.
"""
from __future__ import annotations

import re
import socket
import struct
from pathlib import Path

import numpy as np
import pytest

from droid.brain.runtime import cheader
from droid.brain.cell.cellfile import load_cell
from droid.brain.cell.registry import classes
from droid.brain.db.layouts import FAULT_DEVICE, FT6_STATUS_LAYOUT, LAYOUTS, new_record
from droid.cli import BadInput
from droid.kinematics.transforms import pose_to_T
from droid.sim.ft.netft import CalibrationPage
from droid.subunits.ft import rdt
from droid.subunits.ft.prog import FtCore, FtStation, ft_options, main, wrench_in_tool
from droid.tasks.snoop import status_dict, status_text

ROOT = Path(__file__).resolve().parents[2]
CAL = rdt.Calibration(1e6, 1e3, "N", "N-mm", "test")


# ------------------------------------------------------------------ class, layout, header, snoop


def test_ft6_is_a_class_with_its_layout_in_the_c_header_and_the_docs():
    c = classes()["ft6"]
    assert c.brain["status"] is FT6_STATUS_LAYOUT and c.local["ctrl_status"] is FT6_STATUS_LAYOUT
    assert LAYOUTS[FT6_STATUS_LAYOUT.kind] is FT6_STATUS_LAYOUT
    names = FT6_STATUS_LAYOUT.dtype.names
    for f in ("force_N", "torque_Nm", "force_tool_N", "torque_tool_Nm", "rdt_seq", "ft_seq", "status_word",
              "valid", "saturated", "biased", "sample_age_ms", "dropped", "out_of_order", "bad_datagrams",
              "fault", "tick", "updated_ns", "sample_ns", "stale"):
        assert f in names
    for f in c.copy_fields + c.snoop_fields:
        assert f in names, f
    assert "droid_ft6_status_t" in cheader.generate()
    assert cheader.SHIPPED.read_text() == cheader.generate()
    arch = (ROOT / "docs" / "architecture.md").read_text()
    for f in names[8:]:  # every payload field is named in the architecture doc
        assert f"`{f}`" in arch, f
    assert set(c.drivers) == set(rdt.DRIVERS)


def test_snoop_json_prints_force_and_torque_as_floats():
    rec = new_record(FT6_STATUS_LAYOUT)
    rec["force_N"] = [1.5, -2.25, 3.125]
    rec["torque_Nm"] = [0.0625, -0.5, 0.001]
    rec["sample_age_ms"] = 2.5
    rec["valid"] = 1
    rec["fault"] = FAULT_DEVICE
    d = status_dict(load_cell().subunit("ft"), rec)
    assert d["force_N"] == [1.5, -2.25, 3.125] and d["torque_Nm"] == [0.0625, -0.5, 0.001]
    assert d["sample_age_ms"] == 2.5 and d["valid"] == 1 and d["fault"] == ["device"]
    assert "F [+1.50 -2.25 +3.12] N" in status_text(d)
    import json

    assert json.loads(json.dumps(d))["torque_Nm"] == [0.0625, -0.5, 0.001]  # what `droid-snoop ft --json` prints


# ------------------------------------------------------------------------------ the wire


def test_request_and_record_bytes_are_big_endian_as_the_manual_says():
    assert rdt.request(rdt.CMD_START_REALTIME, 0) == bytes.fromhex("1234 0002 00000000")
    assert rdt.request(rdt.CMD_SET_BIAS) == bytes.fromhex("1234 0042 00000000")
    assert rdt.request(rdt.CMD_STOP, 10) == bytes.fromhex("1234 0000 0000000a")
    raw = rdt.Record(7, 0x01020304, 0x80020000, (1, -1, 2, -2, 3, -3)).pack()
    assert len(raw) == 36
    assert raw[:12] == bytes.fromhex("00000007 01020304 80020000")
    assert raw[12:16] == bytes.fromhex("00000001") and raw[16:20] == bytes.fromhex("ffffffff")


def rec(seq, counts=(0,) * 6, status=0):
    return rdt.Record(seq, seq * 14, status, tuple(counts)).pack()


def test_stream_counts_dropped_misordered_and_bad_datagrams():
    s = rdt.RdtStream()
    assert s.feed(rec(1)).rdt_seq == 1
    assert s.feed(rec(2)).rdt_seq == 2
    assert s.feed(rec(5)).rdt_seq == 5 and s.dropped == 2  # 3 and 4 lost
    assert s.feed(rec(4)) is None and s.out_of_order == 1  # late: not applied
    assert s.feed(rec(5)) is None and s.out_of_order == 2  # duplicate
    assert s.feed(rec(6)[:35]) is None and s.feed(rec(6) + b"\0") is None and s.feed(b"") is None
    assert s.bad_datagrams == 3
    assert s.feed(rec(6)).rdt_seq == 6 and s.last.rdt_seq == 6 and s.records == 4
    s.restart()  # a new request: the sequence starts again at 1
    assert s.feed(rec(1)) is not None and s.dropped == 2
    w = rdt.RdtStream()
    w.feed(rec(0xFFFFFFFF))
    assert w.feed(rec(0)) is not None and w.dropped == 0 and w.out_of_order == 0  # wraps


def page(cpf="1000000", cpt="1000", fu="N", tu="N-mm", extra=""):
    return (f"<?xml version='1.0'?><netft><prodname>x</prodname><cfgcpf>{cpf}</cfgcpf><cfgcpt>{cpt}</cfgcpt>"
            f"<scfgfu>{fu}</scfgfu><scfgtu>{tu}</scfgtu>{extra}</netft>").encode()


def test_calibration_page_is_read_and_converted_to_newton_and_newton_metre():
    c = rdt.parse_calibration(page())
    assert c.n_per_count == pytest.approx(1e-6) and c.nm_per_count == pytest.approx(1e-6)
    c = rdt.parse_calibration(page("1000", "2000", "lbf", "lbf-in"))
    assert c.n_per_count == pytest.approx(4.4482216152605 / 1000)
    assert c.nm_per_count == pytest.approx(0.1129848290276167 / 2000)
    assert rdt.parse_calibration(page(tu="Nmm")).nm_per_count == pytest.approx(1e-6)
    assert rdt.parse_calibration(CAL.xml()) == CAL


@pytest.mark.parametrize("body,why", [
    (b"<netft><cfgcpf>1</cfgcpf", "not XML"),
    (b"garbage \x00\xff", "not XML"),
    (page().replace(b"<cfgcpf>1000000</cfgcpf>", b""), "<cfgcpf> must appear exactly once"),
    (page(extra="<cfgcpt>5</cfgcpt>"), "<cfgcpt> must appear exactly once"),
    (page(cpf="0"), "not a finite number > 0"),
    (page(cpf="-5"), "not a finite number > 0"),
    (page(cpt="nan"), "not a finite number > 0"),
    (page(cpt="lots"), "not a finite number > 0"),
    (page(fu="furlong"), "unknown force unit"),
    (page(tu="N-km"), "unknown torque unit"),
    (b"x" * (rdt.MAX_PAGE_BYTES + 1), "larger than"),
])
def test_a_garbled_calibration_page_is_refused_in_one_line(body, why):
    with pytest.raises(rdt.CalibrationError) as exc:
        rdt.parse_calibration(body, "http://dev/netftapi2.xml")
    assert why in str(exc.value) and "\n" not in str(exc.value)


@pytest.mark.parametrize("url", [
    "udp://127.0.0.1:49152", "netft://", "netft:///path", "netft://127.0.0.1:49152/x",
    "netft://127.0.0.1:99999", "netft://127.0.0.1?rate=5", "netft://127.0.0.1?rate_hz=0",
    "netft://127.0.0.1?rate_hz=nan", "netft://127.0.0.1?rate_hz=5000", "netft://127.0.0.1?http_port=0",
    "netft://127.0.0.1?http_port=x", "netft://127.0.0.1?bias=yes", "netft://127.0.0.1?&&",
])
def test_bad_device_urls_are_refused_with_the_form(url):
    with pytest.raises(BadInput) as exc:
        rdt.parse_url(url)
    assert "\n" not in str(exc.value)


def test_a_good_url_and_its_defaults():
    u = rdt.parse_url("netft://192.168.1.1")
    assert (u.host, u.port, u.rate_hz, u.http_port, u.bias) == ("192.168.1.1", 49152, 100.0, 80, False)
    u = rdt.parse_url("netft://127.0.0.1:5000?rate_hz=250&http_port=8049&bias=1")
    assert (u.port, u.rate_hz, u.http_port, u.bias) == (5000, 250.0, 8049, True)


# ---------------------------------------------------------------------- frames and options


def test_wrench_moves_to_the_tool_frame():
    T = pose_to_T(0.0, 0.0, 150.0, 90.0, 0.0, 0.0)  # tool 150 mm along z, turned 90 deg about z
    f, m = wrench_in_tool([10.0, 0.0, 0.0], [0.0, 0.0, 0.0], T)
    assert np.allclose(f, [0.0, -10.0, 0.0])  # sensor x is the tool's -y
    # m_tool = R^T (m - p x f) with p = (0, 0, 0.15) m: p x f = (0, 1.5, 0) in the sensor frame
    assert np.allclose(m, T[:3, :3].T @ np.array([0.0, -1.5, 0.0]))
    f, m = wrench_in_tool([1.0, 2.0, 3.0], [0.1, 0.2, 0.3], np.eye(4))
    assert np.allclose(f, [1, 2, 3]) and np.allclose(m, [0.1, 0.2, 0.3])


def test_options_of_the_shipped_ft_subunit():
    cell = load_cell()
    opts = ft_options(cell.subunit("ft"), cell)
    assert opts.url == cell.subunit("ft").options["device"] and opts.guard_arm == "arm1"
    assert np.allclose(opts.T_sensor_tool[:3, 3], [0.0, 0.0, 150.0])
    assert cell.subunit("ft").programs == ["droid-ft", "droid-agent"]
    with pytest.raises(BadInput, match="not an ft6"):
        ft_options(cell.subunit("arm1"))


def test_droid_ft_refuses_bad_input_in_one_line(tmp_path, capsys):
    from tests.brain.cellutil import make_cell_file

    path = make_cell_file(tmp_path, "tftbad")
    text = path.read_text().replace('device = "netft://{loopback}:49152?rate_hz=100&http_port=8049"',
                                    'device = "netft://127.0.0.1:49152?rate_hz=99999"')
    assert "rate_hz=99999" in text
    path.write_text(text)
    for args in (["--cell", str(path), "ft"], ["--cell", str(path), "arm1"], ["--cell", str(path), "nosuch"]):
        assert main(args) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("droid-ft: ") and "Traceback" not in err[0], err


# ------------------------------------------------------------- the driver on a scripted device


class ScriptedDevice:
    """A UDP "device" on 127.0.0.1 that records requests and sends what the test says."""

    def __init__(self):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(2.0)
        self.port = self.sock.getsockname()[1]
        self.client = None

    def request(self):
        data, self.client = self.sock.recvfrom(64)
        return struct.unpack(">HHI", data)

    def send(self, *datagrams):
        for d in datagrams:
            self.sock.sendto(d, self.client)

    def close(self):
        self.sock.close()


@pytest.fixture
def scripted():
    dev = ScriptedDevice()
    page_ = CalibrationPage("127.0.0.1", 0, CAL.xml())
    lines = []
    drv = rdt.open_ft(f"netft://127.0.0.1:{dev.port}?http_port={page_.port}")
    station = FtStation(drv, FtCore(np.eye(4), stale_ns=200_000_000), restart_ns=500_000_000, log=lines.append)
    yield dev, page_, drv, station, lines
    drv.close()
    page_.close()
    dev.close()


def settle(station, now_ns, want, tries=200):
    """Step until ``want(fields)`` (datagrams on loopback arrive within microseconds; bounded)."""
    import time

    for _ in range(tries):
        f = station.step(now_ns)
        if want(f):
            return f
        time.sleep(0.005)
    return f


def test_driver_scales_counts_and_counts_every_kind_of_bad_datagram(scripted):
    dev, _page, drv, station, lines = scripted
    f = station.step(0)  # calibrates, sends the start
    assert lines and "1e+06 counts/N" in lines[0]
    assert dev.request() == (0x1234, rdt.CMD_START_REALTIME, 0)
    assert f["valid"] == 0 and f["fault"] == FAULT_DEVICE  # nothing yet
    dev.send(rec(1, (1_500_000, -2_000_000, 0, 250_000, 0, -1_000)))
    f = settle(station, 1_000_000, lambda f: f["records"] == 1)
    assert f["valid"] == 1 and f["fault"] == 0 and f["rdt_seq"] == 1
    assert np.allclose(f["force_N"], [1.5, -2.0, 0.0]) and np.allclose(f["torque_Nm"], [0.25, 0.0, -0.001])
    # a gap, a late one, a duplicate, truncated, oversized, and one from a foreign sender
    other = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        other.sendto(rec(2, (9_000_000,) * 6), ("127.0.0.1", drv.sock.getsockname()[1]))
    finally:
        other.close()
    dev.send(rec(4), rec(3), rec(4), rec(5)[:20], rec(5) + rec(6), rec(5, (3_000_000, 0, 0, 0, 0, 0)))
    f = settle(station, 2_000_000, lambda f: f["rdt_seq"] == 5 and f["bad_datagrams"] == 2)
    assert (f["dropped"], f["out_of_order"], f["bad_datagrams"], f["records"]) == (2, 2, 2, 3)
    assert np.allclose(f["force_N"], [3.0, 0.0, 0.0])  # the foreign record was never applied
    assert f["saturated"] == 0
    dev.send(rec(6, status=rdt.STATUS_ERROR | rdt.STATUS_SATURATION))
    f = settle(station, 3_000_000, lambda f: f["rdt_seq"] == 6)
    assert f["saturated"] == 1 and f["status_word"] == 0x80020000


def test_records_stopping_make_the_status_stale_and_the_stream_is_asked_again(scripted):
    dev, _page, _drv, station, _lines = scripted
    station.step(0)
    dev.request()
    dev.send(rec(1))
    f = settle(station, 10_000_000, lambda f: f["records"] == 1)
    assert f["valid"] == 1 and f["stale"] == 0
    f = station.step(10_000_000 + 199_000_000)  # just inside the stale span
    assert f["valid"] == 1 and f["sample_age_ms"] == pytest.approx(199.0)
    f = station.step(10_000_000 + 200_000_000)  # stale_ticks periods without a record
    assert f["valid"] == 0 and f["stale"] == 1 and f["fault"] == FAULT_DEVICE
    assert dev.request() == (0x1234, rdt.CMD_START_REALTIME, 0)  # asked to stream again
    dev.send(rec(1))  # the new request's sequence starts at 1 again: not "out of order"
    f = settle(station, 300_000_000, lambda f: f["records"] == 2)
    assert f["valid"] == 1 and f["out_of_order"] == 0


def test_a_missing_then_garbled_calibration_page_is_one_line_each_and_no_reading(scripted):
    dev, page_, drv, station, lines = scripted
    page_.page = b"<netft><cfgcpf>oops</cfgcpf></netft>"
    lines.clear()
    for i in range(5):
        f = station.step(i * 600_000_000)
    assert len(lines) == 1 and "calibration" in lines[0] and "retrying" in lines[0], lines
    assert f["valid"] == 0 and f["fault"] == FAULT_DEVICE
    dev.sock.settimeout(0.05)
    with pytest.raises(socket.timeout):
        dev.request()  # never asked to stream without a calibration
    # no page at all: nothing listens on that port any more
    drv.url = rdt.NetFtUrl(drv.url.host, drv.url.port, drv.url.rate_hz, _free_tcp_port(), False)
    f = station.step(10_000_000_000)
    assert len(lines) == 2 and "ConnectionRefusedError" in lines[1] and f["valid"] == 0


def _free_tcp_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def test_bias_from_the_url_is_sent_once_the_stream_runs():
    dev = ScriptedDevice()
    page_ = CalibrationPage("127.0.0.1", 0, CAL.xml())
    drv = rdt.open_ft(f"netft://127.0.0.1:{dev.port}?http_port={page_.port}&bias=1")
    try:
        station = FtStation(drv, FtCore(np.eye(4), 10**9), 10**9, log=lambda line: None)
        f = station.step(0)
        assert dev.request()[1] == rdt.CMD_START_REALTIME and f["biased"] == 0
        dev.send(rec(1))
        f = settle(station, 1, lambda f: f["records"] == 1)
        assert f["biased"] == 1 and dev.request()[1] == rdt.CMD_SET_BIAS
    finally:
        drv.close()
        page_.close()
        dev.close()
    assert re.match(r"^netft$", rdt.NetFtDevice.scheme)


def test_the_ft_subunit_never_imports_the_world_and_the_twin_only_what_sim_may():
    from tests.layering import DROID, droid_imports, within

    for path in (DROID / "subunits" / "ft").glob("*.py"):
        for name in droid_imports(path):
            assert within(name, ("droid.brain", "droid.kinematics", "droid.cli", "droid.numbers",
                                 "droid.subunits.ft")), (path.name, name)
    for path in (DROID / "sim" / "ft").glob("*.py"):
        for name in droid_imports(path):
            assert not within(name, ("droid.tasks", "droid.observe", "droid.experiments")), (path.name, name)
