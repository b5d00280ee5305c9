"""The generated C header matches the Python layouts byte for byte (a C program reads a live db)."""
import shutil
import subprocess

import pytest

from droid.brain.runtime import cheader
from droid.brain.db import layouts as L
from droid.brain.db.shmdb import Database, db_name

C_PROGRAM = r"""
#include <fcntl.h>
#include <semaphore.h>
#include <stdio.h>
#include <string.h>
#include <sys/mman.h>
#include <time.h>
#include <unistd.h>
#include "droid_layouts.h"

int main(int argc, char **argv) {
    int fd = shm_open(argv[1], O_RDWR, 0);
    if (fd < 0) { perror("shm_open"); return 1; }
    droid_arm_status_t *s = mmap(NULL, sizeof *s, PROT_READ | PROT_WRITE, MAP_SHARED, fd, 0);
    if (s == MAP_FAILED) { perror("mmap"); return 1; }
    if (s->magic != DROID_MAGIC || s->kind != DROID_ARM_STATUS_KIND ||
        s->version != DROID_ARM_STATUS_VERSION) { fprintf(stderr, "layout mismatch\n"); return 2; }
    sem_t *sem = sem_open(argv[1], 0);
    if (sem == SEM_FAILED) { perror("sem_open"); return 1; }
    struct timespec ts; clock_gettime(CLOCK_REALTIME, &ts); ts.tv_sec += 1;
    if (sem_timedwait(sem, &ts) != 0) { perror("sem_timedwait"); return 1; }
    s->holder_pid = getpid();
    printf("%.3f %d %d %.3f %llu\n", s->y, s->encoder_pos[4], s->busy, s->R[1][2],
           (unsigned long long)s->tick);
    s->encoder_cmd[5] = -1234;   /* written from C, read back by Python */
    s->holder_pid = 0;
    sem_post(sem);
    return 0;
}
"""


def test_shipped_header_is_current():
    assert cheader.SHIPPED.read_text() == cheader.generate(), "run: droid-cheader -o droid/include/droid_layouts.h"


@pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc not installed")
def test_c_program_reads_live_database(tmp_path, cell_name):
    (tmp_path / "droid_layouts.h").write_text(cheader.generate())
    src = tmp_path / "reader.c"
    src.write_text(C_PROGRAM)
    exe = tmp_path / "reader"
    subprocess.run(["gcc", "-std=c11", "-D_GNU_SOURCE", "-Wall", "-Werror", f"-I{tmp_path}",
                    str(src), "-o", str(exe), "-lpthread", "-lrt"], check=True)
    name = db_name(cell_name, "arm1", "status")
    db = Database(name, L.ARM_STATUS_LAYOUT, create=True)
    try:
        R = [[1, 0, 0], [0, 0.6, -0.8], [0, 0.8, 0.6]]
        db.update(y=-321.25, encoder_pos=[0, 0, 0, 0, 98765, 0], busy=17, R=R, tick=2**40 + 3)
        out = subprocess.run([str(exe), name], capture_output=True, text=True, timeout=10)
        assert out.returncode == 0, out.stderr
        assert out.stdout.split() == ["-321.250", "98765", "17", "-0.800", str(2**40 + 3)]
        assert int(db.read()["encoder_cmd"][5]) == -1234
    finally:
        db.unlink()
