"""VME driver: register access, URL handling, the three backends (thesis §4.1.2)."""
from __future__ import annotations

import mmap
import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from droid.cli import EXIT_BAD_INPUT, EXIT_RUNTIME
from droid.sim.reis.plant import ReisPlant
from droid.sim.reis.vme_shm import SharedVmeMap
from droid.subunits.reis import vme_map as vm
from droid.subunits.reis.vme import VmeBus, VmeOpenError, VmeUrlError, open_vme


def test_map_layout_fits_and_does_not_overlap():
    spans = [(vm.ENCODER_OFFSET, 12), (vm.DAC_OFFSET, 12), (vm.LIMIT_SWITCH_OFFSET, 2), (vm.AMP_STATUS_OFFSET, 2)]
    spans += [(o, 2) for o in vm.WATCHDOG_OFFSETS]
    spans.sort()
    for (a, na), (b, _) in zip(spans, spans[1:]):
        assert a + na <= b
    assert spans[-1][0] + spans[-1][1] <= vm.MAP_SIZE
    assert all(off % 2 == 0 for off, _ in spans)


def test_encoders_are_little_endian_u16_at_their_offsets():
    buf = bytearray(vm.MAP_SIZE)
    struct.pack_into("<6H", buf, vm.ENCODER_OFFSET, 0, 1, 255, 256, 32768, 65535)
    bus = VmeBus.from_buffer(buf)
    assert bus.read_encoders_raw() == (0, 1, 255, 256, 32768, 65535)
    assert buf[vm.ENCODER_OFFSET + 6 : vm.ENCODER_OFFSET + 8] == b"\x00\x01"  # 256, little-endian
    bus.close()


@given(st.lists(st.integers(-100_000, 100_000), min_size=6, max_size=6))
def test_write_dacs_clamps_to_12_bit_signed(values):
    buf = bytearray(vm.MAP_SIZE)
    with VmeBus.from_buffer(buf) as bus:
        written = bus.write_dacs(values)
        expected = tuple(min(2047, max(-2048, v)) for v in values)
        assert written == expected
        assert struct.unpack_from("<6h", buf, vm.DAC_OFFSET) == expected
        assert bus.read_dacs() == expected


def test_write_dacs_needs_six_values():
    with VmeBus.from_buffer(bytearray(vm.MAP_SIZE)) as bus, pytest.raises(ValueError):
        bus.write_dacs([0] * 5)


@given(st.integers(0, 0xFFFF))
def test_limit_switch_bits_map_to_joints(bits):
    buf = bytearray(vm.MAP_SIZE)
    struct.pack_into("<H", buf, vm.LIMIT_SWITCH_OFFSET, bits)
    with VmeBus.from_buffer(buf) as bus:
        assert bus.read_limit_switches() == tuple(bool(bits & (1 << j)) for j in range(6))


def test_kick_watchdog_changes_both_registers_every_time():
    buf = bytearray(vm.MAP_SIZE)
    with VmeBus.from_buffer(buf) as bus:
        seen = []
        for _ in range(5):
            bus.kick_watchdog()
            seen.append(tuple(struct.unpack_from("<H", buf, o)[0] for o in vm.WATCHDOG_OFFSETS))
        for a, b in zip(seen, seen[1:]):
            assert a[0] != b[0] and a[1] != b[1]


def test_register_access_checks_offsets():
    with VmeBus.from_buffer(bytearray(vm.MAP_SIZE)) as bus:
        bus.write_i16(vm.DAC_OFFSET, -5)
        assert bus.read_i16(vm.DAC_OFFSET) == -5
        assert bus.read_u16(vm.DAC_OFFSET) == 65531
        for bad in (1, -2, vm.MAP_SIZE, vm.MAP_SIZE - 1):
            with pytest.raises(ValueError):
                bus.read_u16(bad)


def test_buffer_too_small_or_read_only_is_rejected():
    with pytest.raises(VmeOpenError):
        VmeBus.from_buffer(bytearray(vm.MAP_SIZE - 2))
    with pytest.raises(VmeOpenError):
        VmeBus.from_buffer(bytes(vm.MAP_SIZE))


def test_close_is_idempotent_and_blocks_access():
    bus = VmeBus.from_buffer(bytearray(vm.MAP_SIZE))
    bus.close()
    bus.close()
    assert bus.closed
    with pytest.raises(Exception):
        bus.read_encoders_raw()


@pytest.mark.parametrize(
    "url, expect",
    [
        ("tcp://host:1", "shm://NAME"),
        ("/dev/mem", "shm://NAME"),
        ("shm://", "shm://NAME"),
        ("shm://a/b", "shm://NAME"),
        ("shm://ok?x=1", "shm://NAME"),
        ("mem://relative/path", "mem:///PATH?offset="),
        ("mem:///dev/mem?size=4", "unknown option 'size'"),
        ("mem:///dev/mem?offset=zz", "not an integer"),
        ("mem:///dev/mem?offset=-16", "offset must be >= 0"),
    ],
)
def test_bad_urls_are_rejected_with_the_expected_form(url, expect):
    with pytest.raises(VmeUrlError) as err:
        open_vme(url)
    assert expect in str(err.value)
    assert err.value.exit_code == EXIT_BAD_INPUT


def test_missing_shm_object_is_a_runtime_failure(cell_name):
    with pytest.raises(VmeOpenError) as err:
        open_vme(f"shm://droid.{cell_name}.arm1.vme")
    assert "droid-sim" in str(err.value)
    assert err.value.exit_code == EXIT_RUNTIME


@pytest.mark.parametrize("offset", [0, 0x40, 0x1000 + 0x80, 3 * mmap.ALLOCATIONGRANULARITY + 0x20])
def test_mem_url_maps_a_file_at_an_offset(tmp_path, offset):
    path = tmp_path / "vme.bin"
    path.write_bytes(bytes(offset + vm.MAP_SIZE + 64))
    with open_vme(f"mem://{path}?offset={offset:#x}") as bus:
        bus.write_dacs([1, -1, 2047, -2048, 0, 100])
        bus.kick_watchdog()
    data = path.read_bytes()
    assert struct.unpack_from("<6h", data, offset + vm.DAC_OFFSET) == (1, -1, 2047, -2048, 0, 100)
    assert data[:offset] == bytes(offset)  # nothing written before the window


def test_mem_url_file_too_short(tmp_path):
    path = tmp_path / "short.bin"
    path.write_bytes(bytes(vm.MAP_SIZE))
    with pytest.raises(VmeOpenError):
        open_vme(f"mem://{path}?offset=0x10")
    with pytest.raises(VmeOpenError):
        open_vme(f"mem://{tmp_path}/absent.bin")


def test_shm_url_reaches_the_simulated_robot(cell_name):
    """droid-sim's plant on the shared map; the driver in its own mapping sees it."""
    name = f"droid.{cell_name}.arm1.vme"
    with SharedVmeMap.create(name) as shared:
        plant = ReisPlant(seed=7, regs=shared.buf)
        with open_vme(shared.url) as bus:
            assert bus.read_encoders_raw() == plant.encoder_raw
            assert not bus.amps_powered  # until the watchdog runs
            bus.kick_watchdog()
            plant.advance(0.001)
            assert bus.amps_powered
            bus.write_dacs([2047, 0, 0, 0, 0, 0])
            for _ in range(20):
                bus.kick_watchdog()
                plant.advance(0.002)
            assert bus.read_encoders_raw() == plant.encoder_raw
            assert plant.motor_speed_counts_per_s[0] > 0
        plant.close()
