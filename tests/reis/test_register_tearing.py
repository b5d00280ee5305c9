"""Registers shared between processes are never seen half-written (a real bug: struct.pack_into
zero-fills before writing, so droid-servo read encoder registers as 0 and faulted)."""
import multiprocessing as mp

from droid.sim.reis.plant import ReisPlant
from droid.sim.reis.vme_shm import SharedVmeMap
from droid.subunits.reis.vme import open_vme

CTX = mp.get_context("fork")


def _reader(url, stop, result):
    bus = open_vme(url)
    zeros = 0
    reads = 0
    while not stop.is_set():
        raw = bus.read_encoders_raw()
        reads += 1
        zeros += sum(1 for v in raw if v == 0)
    bus.close()
    result.put((reads, zeros))


def test_encoder_registers_never_read_zero_while_the_plant_writes(cell_name):
    with SharedVmeMap.create(f"droid.{cell_name}.arm1.vme") as shared:
        plant = ReisPlant(seed=1, regs=shared.buf, encoder_power_up_counts=[1000, 2000, 3000, 4000, 5000, 6000])
        stop, result = CTX.Event(), CTX.Queue()
        p = CTX.Process(target=_reader, args=(shared.url, stop, result))
        p.start()
        try:
            for _ in range(20000):  # rewrite the same non-zero values as fast as possible
                plant._write_outputs()
        finally:
            stop.set()
            reads, zeros = result.get(timeout=10)
            p.join(10)
        plant.close()
    assert reads > 0
    assert zeros == 0, f"{zeros} zero readings in {reads} reads"
