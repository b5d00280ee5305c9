/* droid._kernel: the compiled 500 Hz pair (issue 28 item 1) -- the Reis plant twin's exact
 * zero-order-hold step and the servo program's PID (thesis §4.1.5.1).
 *
 * One implementation, called by droid.sim.reis.plant.ReisPlant (lockstep trials, droid-sim's
 * arm device) and droid.subunits.reis.pid (droid-servo and lockstep alike) when
 * DROID_KERNEL=c (droid/kernel.py; docs/reis.md "The compiled kernel").
 *
 * Bit-identical to the Python reference, by construction:
 *  - built with -O2 -fno-fast-math -ffp-contract=off (setup.py): no FMA contraction, no
 *    reassociation; every scalar expression is written in the Python code's order;
 *  - the two matrix-vector products ([Phi | Gamma] @ [x; tau], 24x36, and the friction
 *    response, 24x6) call the very cblas_dgemv numpy's matmul calls (its bundled OpenBLAS,
 *    resolved at import by droid/kernel.py and checked bit for bit against numpy there), so
 *    the sums run in OpenBLAS's order with its kernels;
 *  - sin() is libm's, the function CPython's math.sin calls;
 *  - Python's round() (half to even) is nearbyint() in the default rounding mode.
 * No Python objects are created in the hot paths but the results.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

/* the VME register map (droid.subunits.reis.vme_map; droid/kernel.py checks these) */
#define N 6
#define ENCODER_OFFSET 0x00
#define DAC_OFFSET 0x10
#define LIMIT_SWITCH_OFFSET 0x20
#define AMP_STATUS_OFFSET 0x28
#define MAP_MIN_SIZE 0x2A
#define ENCODER_MODULUS 65536
#define DAC_MIN (-2048)
#define DAC_MAX 2047
#define AMP_STATUS_POWERED 0x0001
#define AMP_STATUS_WATCHDOG_FAULT 0x0002

/* the plant's constants, one float64 vector (droid/kernel.py: plant_constants) */
enum {
    C_TAU_PER_DAC = 0, C_TAU_MAX = 6, C_TAU_MAX_W0 = 12, C_TAU_C = 18, C_TAU_BRAKE = 24,
    C_CPR = 30, C_SW = 36, C_SIDE = 42, C_BAL = 48, C_LEN = 49
};

/* cblas_dgemv(order, trans, m, n, alpha, a, lda, x, incx, beta, y, incy), 64-bit or 32-bit ints */
typedef void (*dgemv64_t)(int, int, int64_t, int64_t, double, const double *, int64_t, const double *,
                          int64_t, double, double *, int64_t);
typedef void (*dgemv32_t)(int, int, int32_t, int32_t, double, const double *, int32_t, const double *,
                          int32_t, double, double *, int32_t);
static void *gemv_fn = NULL;
static int gemv_int64 = 1;
enum { CBLAS_ROW_MAJOR = 101, CBLAS_NO_TRANS = 111 };

/* y = a @ x for a C-contiguous (m, n) a: numpy's matmul on such arrays */
static void matvec(const double *a, int m, int n, const double *x, double *y)
{
    if (gemv_int64)
        ((dgemv64_t)gemv_fn)(CBLAS_ROW_MAJOR, CBLAS_NO_TRANS, m, n, 1.0, a, n, x, 1, 0.0, y, 1);
    else
        ((dgemv32_t)gemv_fn)(CBLAS_ROW_MAJOR, CBLAS_NO_TRANS, m, n, 1.0, a, n, x, 1, 0.0, y, 1);
}

static PyObject *set_gemv(PyObject *self, PyObject *args)
{
    unsigned long long addr;
    int int64;
    if (!PyArg_ParseTuple(args, "Kp", &addr, &int64))
        return NULL;
    gemv_fn = (void *)(uintptr_t)addr;
    gemv_int64 = int64;
    Py_RETURN_NONE;
}

static PyObject *py_matvec(PyObject *self, PyObject *const *args, Py_ssize_t nargs);

/* -- buffers --------------------------------------------------------------------------------- */
typedef struct {
    Py_buffer b[12];
    int n;
} Bufs;

static void release(Bufs *bs)
{
    for (int i = 0; i < bs->n; i++)
        PyBuffer_Release(&bs->b[i]);
    bs->n = 0;
}

/* a C-contiguous buffer of exactly ``len`` bytes (len < 0: at least -len), writable if asked */
static void *get(Bufs *bs, PyObject *o, Py_ssize_t len, int writable, const char *what)
{
    Py_buffer *b = &bs->b[bs->n];
    if (PyObject_GetBuffer(o, b, PyBUF_C_CONTIGUOUS | (writable ? PyBUF_WRITABLE : 0)) < 0)
        return NULL;
    bs->n++;
    if ((len >= 0 && b->len != len) || (len < 0 && b->len < -len)) {
        PyErr_Format(PyExc_ValueError, "%s: %zd bytes, need %zd", what, b->len, len < 0 ? -len : len);
        return NULL;
    }
    return b->buf;
}

static inline double rd_i16(const unsigned char *p) { return (double)(int16_t)(uint16_t)(p[0] | (p[1] << 8)); }
static inline void wr_u16(unsigned char *p, unsigned v) { p[0] = (unsigned char)(v & 0xFF); p[1] = (unsigned char)(v >> 8); }

/* -- the plant's outputs (ReisPlant._write_outputs) ------------------------------------------- */
/* encoders (floor(theta * cpr) + offset) mod 2^16, the switch bits (side * (q - sw) > 0), AMP_STATUS;
   enc: the six counter values written.  -1 with an exception set if a motor angle is not finite. */
static int write_outputs(unsigned char *regs, const double *k, const double *theta, const double *q,
                         const int64_t *offset, int amps_on, int wd_fault, long enc[N])
{
    unsigned bits = 0;
    for (int j = 0; j < N; j++) {
        double f = floor(theta[j] * k[C_CPR + j]);
        if (!isfinite(f)) {  /* as Python's math.floor: NaN -> ValueError, inf -> OverflowError */
            PyErr_SetString(isnan(f) ? PyExc_ValueError : PyExc_OverflowError,
                            isnan(f) ? "cannot convert float NaN to integer" : "cannot convert float infinity to integer");
            return -1;
        }
        /* (floor + offset) mod 2^16 as Python's ints do it, for any size of floor: fmod of an
           integral double is exact, and (a + b) mod m = ((a mod m) + b mod m) mod m */
        long long v = ((long long)fmod(f, (double)ENCODER_MODULUS) + offset[j] % ENCODER_MODULUS) % ENCODER_MODULUS;
        if (v < 0)
            v += ENCODER_MODULUS;
        enc[j] = (long)v;
        wr_u16(regs + ENCODER_OFFSET + 2 * j, (unsigned)v);
        if (k[C_SIDE + j] * (q[j] - k[C_SW + j]) > 0.0)
            bits |= 1u << j;
    }
    wr_u16(regs + LIMIT_SWITCH_OFFSET, bits);
    wr_u16(regs + AMP_STATUS_OFFSET, (amps_on ? AMP_STATUS_POWERED : 0) | (wd_fault ? AMP_STATUS_WATCHDOG_FAULT : 0));
    return 0;
}

static PyObject *enc_tuple(const long enc[N])
{
    PyObject *t = PyTuple_New(N);
    if (t == NULL)
        return NULL;
    for (int j = 0; j < N; j++) {
        PyObject *v = PyLong_FromLong(enc[j]);
        if (v == NULL) {
            Py_DECREF(t);
            return NULL;
        }
        PyTuple_SET_ITEM(t, j, v);
    }
    return t;
}

/* exact_step(regs, consts, pg, g_m, theta, omega, q, qd, tau_link, ext, amps_on, wd_fault, offset, x)
 *
 * ReisPlant._integrate's exact branch and _step_exact (droid/sim/reis/plant.py), the same
 * operations in the same order: the DAC registers -> motor torques (clipped to +-tau_max,
 * then to the back-EMF range at the step's start speed; 0 and the brake's friction when the
 * amplifiers are off), z = [theta, omega, q, qd, drive, -tau_link (+ balancer, + ext)],
 * free = [Phi | Gamma] @ z, Coulomb friction with stiction (Karnopp) through the friction
 * response g_m, then the encoders, switches and AMP_STATUS.  Writes the new state into x
 * (24 float64: theta, omega, q, qd) and returns the six encoder values written.
 * Units: rad, rad/s, N m; regs: the VME map's bytes.  */
static PyObject *exact_step(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 14) {
        PyErr_SetString(PyExc_TypeError, "exact_step takes 14 arguments");
        return NULL;
    }
    if (gemv_fn == NULL) {
        PyErr_SetString(PyExc_RuntimeError, "droid._kernel: no BLAS dgemv set (droid.kernel sets it)");
        return NULL;
    }
    Bufs bs = {.n = 0};
    long enc[N];
    unsigned char *regs = get(&bs, args[0], -MAP_MIN_SIZE, 1, "regs");
    const double *k = regs ? get(&bs, args[1], C_LEN * 8, 0, "consts") : NULL;
    const double *pg = k ? get(&bs, args[2], 24 * 36 * 8, 0, "pg") : NULL;
    const double *gm = pg ? get(&bs, args[3], 24 * 6 * 8, 0, "g_m") : NULL;
    const double *theta = gm ? get(&bs, args[4], 6 * 8, 0, "theta") : NULL;
    const double *omega = theta ? get(&bs, args[5], 6 * 8, 0, "omega") : NULL;
    const double *q = omega ? get(&bs, args[6], 6 * 8, 0, "q") : NULL;
    const double *qd = q ? get(&bs, args[7], 6 * 8, 0, "qd") : NULL;
    const double *tl = qd ? get(&bs, args[8], 6 * 8, 0, "tau_link") : NULL;
    const double *ext = NULL;
    if (tl && args[9] != Py_None && (ext = get(&bs, args[9], 6 * 8, 0, "ext")) == NULL)
        tl = NULL;
    int amps_on = tl ? PyObject_IsTrue(args[10]) : -1;
    int wd_fault = amps_on >= 0 ? PyObject_IsTrue(args[11]) : -1;
    const int64_t *offset = wd_fault >= 0 ? get(&bs, args[12], 6 * 8, 0, "offset") : NULL;
    double *x = offset ? get(&bs, args[13], 24 * 8, 1, "x") : NULL;
    if (x == NULL) {
        release(&bs);
        return NULL;
    }
    double z[36], tau_c[N], free_[24], kin[N], fric[N], gk[24];
    /* the drive torques (ReisPlant._integrate's fused loop) and the friction level */
    for (int j = 0; j < N; j++) {
        double v = 0.0;
        if (amps_on) {
            double tm = k[C_TAU_MAX + j], a = k[C_TAU_MAX_W0 + j], w = omega[j], b;
            double d = rd_i16(regs + DAC_OFFSET + 2 * j);
            d = d > DAC_MIN ? d : DAC_MIN;
            v = (d < DAC_MAX ? d : DAC_MAX) * k[C_TAU_PER_DAC + j];
            v = v > -tm ? v : -tm;
            v = v < tm ? v : tm;
            b = -tm - a * w;
            v = v > b ? v : b;
            b = tm - a * w;
            v = v < b ? v : b;
            tau_c[j] = k[C_TAU_C + j];
        } else {
            tau_c[j] = k[C_TAU_C + j] + k[C_TAU_BRAKE + j];
        }
        z[j] = theta[j];
        z[6 + j] = omega[j];
        z[12 + j] = q[j];
        z[18 + j] = qd[j];
        z[24 + j] = v;
        z[30 + j] = -tl[j];
    }
    {
        double nl = -tl[1], bal = k[C_BAL];
        if (bal != 0.0)
            nl -= bal * sin(q[1]);
        z[31] = nl;
    }
    if (ext != NULL)
        for (int j = 0; j < N; j++)
            z[30 + j] += ext[j];
    matvec(pg, 24, 36, z, free_);
    int keep[N] = {0, 0, 0, 0, 0, 0}, moving = 0;
    for (int j = 0; j < N; j++)
        moving |= omega[j] != 0.0;  /* Python's any(om): NaN counts as moving */
    if (moving) {
        for (int j = 0; j < N; j++) {
            double w = omega[j], tc = tau_c[j];
            kin[j] = w > 0.0 ? -tc : (w < 0.0 ? tc : -0.0);
        }
        matvec(gm, 24, 6, kin, gk);
        for (int i = 0; i < 24; i++)
            x[i] = free_[i] + gk[i];
        int all = 1;
        for (int j = 0; j < N; j++) {
            keep[j] = x[6 + j] * omega[j] > 0.0;
            all &= keep[j];
        }
        if (all)
            goto out;
    }
    {
        int rest[N], nrest = 0;
        for (int j = 0; j < N; j++) {
            double tc = tau_c[j];
            if (keep[j]) {
                fric[j] = kin[j];
                continue;
            }
            double w_end = free_[6 + j];
            double stick = -w_end / gm[(6 + j) * 6 + j];
            if (-tc <= stick && stick <= tc) {
                fric[j] = stick;
                rest[nrest++] = j;
            } else {
                fric[j] = w_end > 0.0 ? -tc : tc;
            }
        }
        matvec(gm, 24, 6, fric, gk);
        for (int i = 0; i < 24; i++)
            x[i] = free_[i] + gk[i];
        for (int r = 0; r < nrest; r++) {
            x[rest[r]] = theta[rest[r]];
            x[6 + rest[r]] = 0.0;
        }
    }
out:
    if (write_outputs(regs, k, x, x + 12, offset, amps_on, wd_fault, enc) < 0) {
        release(&bs);
        return NULL;
    }
    release(&bs);
    return enc_tuple(enc);
}

/* write_outputs(regs, consts, theta, q, amps_on, wd_fault, offset) -> the six encoder values:
 * ReisPlant._write_outputs for the other integrators (droid-sim's rigid drives). */
static PyObject *py_write_outputs(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 7) {
        PyErr_SetString(PyExc_TypeError, "write_outputs takes 7 arguments");
        return NULL;
    }
    Bufs bs = {.n = 0};
    long enc[N];
    unsigned char *regs = get(&bs, args[0], -MAP_MIN_SIZE, 1, "regs");
    const double *k = regs ? get(&bs, args[1], C_LEN * 8, 0, "consts") : NULL;
    const double *theta = k ? get(&bs, args[2], 6 * 8, 0, "theta") : NULL;
    const double *q = theta ? get(&bs, args[3], 6 * 8, 0, "q") : NULL;
    int amps_on = q ? PyObject_IsTrue(args[4]) : -1;
    int wd_fault = amps_on >= 0 ? PyObject_IsTrue(args[5]) : -1;
    const int64_t *offset = wd_fault >= 0 ? get(&bs, args[6], 6 * 8, 0, "offset") : NULL;
    if (offset == NULL || write_outputs(regs, k, theta, q, offset, amps_on, wd_fault, enc) < 0) {
        release(&bs);
        return NULL;
    }
    release(&bs);
    return enc_tuple(enc);
}

/* matvec(a, x, y): y = a @ x through the dgemv set (for droid/kernel.py's bit check) */
static PyObject *py_matvec(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 3) {
        PyErr_SetString(PyExc_TypeError, "matvec takes 3 arguments");
        return NULL;
    }
    if (gemv_fn == NULL) {
        PyErr_SetString(PyExc_RuntimeError, "droid._kernel: no BLAS dgemv set");
        return NULL;
    }
    Bufs bs = {.n = 0};
    const double *a = get(&bs, args[0], -8, 0, "a");
    const double *x = a ? get(&bs, args[1], -8, 0, "x") : NULL;
    double *y = x ? get(&bs, args[2], -8, 1, "y") : NULL;
    if (y == NULL) {
        release(&bs);
        return NULL;
    }
    Py_ssize_t n = bs.b[1].len / 8, m = bs.b[2].len / 8;
    if (bs.b[0].len != m * n * 8) {
        release(&bs);
        PyErr_SetString(PyExc_ValueError, "matvec: a is not len(y) x len(x)");
        return NULL;
    }
    matvec(a, (int)m, (int)n, x, y);
    release(&bs);
    Py_RETURN_NONE;
}

/* -- the servo's PID (thesis §4.1.5.1; droid/subunits/reis/pid.py) ------------------------------ */
/* Pid.step's arithmetic, in its order, on n channels: gains g (5, n), state st (2, n: the integrals,
 * then the previous errors; both updated), errors e_now [counts].  A list of floats, or (rounded) a
 * tuple of ints rounded half to even as round() does; NULL with an exception on failure. */
static PyObject *pid_run(const double *g, double *st, Py_ssize_t n, int first, const double *e_now, int rounded)
{
    const double *kp = g, *ki = g + n, *kd = g + 2 * n, *lim_ = g + 3 * n;
    double lo = g[4 * n], hi = g[4 * n + 1];
    double *integral = st, *prev = st + n;
    double outv[64];
    for (Py_ssize_t j = 0; j < n; j++) {
        double e = e_now[j], ep = first ? e : prev[j], lim = lim_[j], i0 = integral[j];
        double pd = kp[j] * e + kd[j] * (e - ep);
        double candidate = i0 + ki[j] * e;
        if (candidate > lim)
            candidate = lim;
        else if (candidate < -lim)
            candidate = -lim;
        double u = pd + candidate;
        if (!((u > hi && e > 0.0) || (u < lo && e < 0.0)))
            integral[j] = i0 = candidate;
        u = pd + i0;
        outv[j] = u > hi ? hi : (u < lo ? lo : u);
    }
    for (Py_ssize_t j = 0; j < n; j++)
        prev[j] = e_now[j];
    PyObject *out = rounded ? PyTuple_New(n) : PyList_New(n);  /* as Pid.step_rounded / Pid.step */
    if (out == NULL)
        return NULL;
    for (Py_ssize_t j = 0; j < n; j++) {
        double u = outv[j];
        PyObject *v;
        if (rounded) {
            double r = nearbyint(u);  /* round(): half to even */
            if (isfinite(r)) {
                v = PyLong_FromDouble(r);
            } else {  /* round(nan) raises ValueError, round(inf) OverflowError */
                v = NULL;
                PyErr_SetString(isnan(r) ? PyExc_ValueError : PyExc_OverflowError,
                                "cannot convert float NaN or infinity to integer");
            }
        } else {
            v = PyFloat_FromDouble(u);
        }
        if (v == NULL) {
            Py_DECREF(out);
            return NULL;
        }
        if (rounded)
            PyTuple_SET_ITEM(out, j, v);
        else
            PyList_SET_ITEM(out, j, v);
    }
    return out;
}

/* pid_step(gains, state, errors, rounded) -> outputs
 * gains: float64 (5, n) -- kp, ki, kd, integral limit, then [out_min, out_max, ...];
 * state: float64 (2, n) -- the integrals (updated) and the previous errors (updated);
 * first: true when there is no previous error (after a reset: no derivative kick);
 * errors: the n errors [counts] (a sequence of ints or floats).
 * Returns the n limited outputs [DAC counts]: a list of floats, or a tuple of Python ints rounded
 * half to even (ServoCore.step's round()) when ``rounded``.  Pid.step's arithmetic, in its order. */
static PyObject *pid_step(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 5) {
        PyErr_SetString(PyExc_TypeError, "pid_step takes 5 arguments");
        return NULL;
    }
    Bufs bs = {.n = 0};
    const double *g = get(&bs, args[0], -8, 0, "gains");
    double *st = g ? get(&bs, args[1], -8, 1, "state") : NULL;
    if (st == NULL) {
        release(&bs);
        return NULL;
    }
    Py_ssize_t n = bs.b[1].len / 16;
    if (n > 64 || bs.b[0].len != 5 * n * 8 || n < 1) {
        release(&bs);
        PyErr_SetString(PyExc_ValueError, "pid_step: gains (5, n) and state (2, n), 1 <= n <= 64");
        return NULL;
    }
    int first = PyObject_IsTrue(args[2]);
    int rounded = PyObject_IsTrue(args[4]);
    PyObject *seq = PySequence_Fast(args[3], "pid_step: errors must be a sequence");
    if (first < 0 || rounded < 0 || seq == NULL) {
        Py_XDECREF(seq);
        release(&bs);
        return NULL;
    }
    if (PySequence_Fast_GET_SIZE(seq) != n) {
        Py_DECREF(seq);
        release(&bs);
        PyErr_Format(PyExc_ValueError, "pid_step: %zd errors, need %zd", PySequence_Fast_GET_SIZE(seq), n);
        return NULL;
    }
    double e_now[64];
    PyObject **items = PySequence_Fast_ITEMS(seq);
    for (Py_ssize_t j = 0; j < n; j++) {
        e_now[j] = PyFloat_AsDouble(items[j]);  /* float(x): exact for ints below 2^53 */
        if (e_now[j] == -1.0 && PyErr_Occurred()) {
            Py_DECREF(seq);
            release(&bs);
            return NULL;
        }
    }
    Py_DECREF(seq);
    PyObject *out = pid_run(g, st, n, first, e_now, rounded);
    release(&bs);
    return out;
}

/* -- the servo tick's integer parts (droid/subunits/reis/servo.py, vme.py) ------------------------- */
/* extend_counters(pos, raw, span, max_step, out) -> jumped
 * ServoCore._read_encoders: the six 16-bit counters ``raw`` [counts] extended to unbounded counts
 * from the last positions ``pos`` (int64) into ``out`` (int64); True if one moved more than
 * ``max_step`` counts (an encoder jump, thesis §4.1.5.1's sanity check). */
static PyObject *extend_counters(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 5) {
        PyErr_SetString(PyExc_TypeError, "extend_counters takes 5 arguments");
        return NULL;
    }
    long long span = PyLong_AsLongLong(args[2]), jump = PyLong_AsLongLong(args[3]);
    if (PyErr_Occurred())
        return NULL;
    if (span <= 0 || span > (1LL << 32)) {
        PyErr_SetString(PyExc_ValueError, "extend_counters: span out of range");
        return NULL;
    }
    PyObject *seq = PySequence_Fast(args[1], "extend_counters: raw must be a sequence");
    if (seq == NULL)
        return NULL;
    if (PySequence_Fast_GET_SIZE(seq) != N) {
        PyErr_Format(PyExc_ValueError, "need %d encoder values, got %zd", N, PySequence_Fast_GET_SIZE(seq));
        Py_DECREF(seq);
        return NULL;
    }
    long long raw[N];
    for (int j = 0; j < N; j++) {
        PyObject *o = PySequence_Fast_GET_ITEM(seq, j);
        PyObject *i = PyNumber_Long(o);  /* int(x), as the Python reference does */
        raw[j] = i ? PyLong_AsLongLong(i) : -1;
        Py_XDECREF(i);
        if (i == NULL || (raw[j] == -1 && PyErr_Occurred())) {
            Py_DECREF(seq);
            return NULL;
        }
    }
    Py_DECREF(seq);
    Bufs bs = {.n = 0};
    const int64_t *pos = get(&bs, args[0], N * 8, 0, "pos");
    int64_t *out = pos ? get(&bs, args[4], N * 8, 1, "out") : NULL;
    if (out == NULL) {
        release(&bs);
        return NULL;
    }
    long long half = span >> 1;
    int jumped = 0;
    for (int j = 0; j < N; j++) {
        long long delta = (raw[j] - pos[j]) % span;  /* Python's %: the result has the sign of span */
        if (delta < 0)
            delta += span;
        if (delta >= half)
            delta -= span;
        if (delta > jump || -delta > jump)
            jumped = 1;
        out[j] = pos[j] + delta;
    }
    release(&bs);
    return PyBool_FromLong(jumped);
}

/* write_dacs(regs, values) -> the six values written, or None
 * VmeBus.write_dacs for six Python ints (ServoCore.step's output): clamped to the DAC's
 * -2048..2047 and stored little-endian; None (nothing written) for anything else, which the
 * Python driver then handles (floats: round half to even first). */
static PyObject *write_dacs(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "write_dacs takes 2 arguments");
        return NULL;
    }
    PyObject *v = args[1];
    if (!PyTuple_CheckExact(v) && !PyList_CheckExact(v))
        Py_RETURN_NONE;
    if (PySequence_Fast_GET_SIZE(v) != N)
        Py_RETURN_NONE;
    long d[N];
    int same = 1;
    for (int j = 0; j < N; j++) {
        PyObject *o = PySequence_Fast_GET_ITEM(v, j);
        if (!PyLong_CheckExact(o))
            Py_RETURN_NONE;
        int overflow = 0;
        long long x = PyLong_AsLongLongAndOverflow(o, &overflow);
        if (overflow) {
            x = overflow > 0 ? DAC_MAX : DAC_MIN;
            same = 0;
        } else if (x == -1 && PyErr_Occurred()) {
            return NULL;
        }
        d[j] = x < DAC_MIN ? DAC_MIN : (x > DAC_MAX ? DAC_MAX : (long)x);
        same &= d[j] == x;
    }
    Bufs bs = {.n = 0};
    unsigned char *regs = get(&bs, args[0], -MAP_MIN_SIZE, 1, "regs");
    if (regs == NULL) {
        release(&bs);
        return NULL;
    }
    for (int j = 0; j < N; j++)
        wr_u16(regs + DAC_OFFSET + 2 * j, (unsigned)(uint16_t)(int16_t)d[j]);
    release(&bs);
    if (same && PyTuple_CheckExact(v)) {  /* nothing clamped: the caller's tuple is the answer */
        Py_INCREF(v);
        return v;
    }
    return enc_tuple(d);
}

/* servo_tail(target, previous, lo, hi, pos, fe_max, vel, gains, state, first) -> dacs or None
 * ServoCore.step after the tick's target is picked (thesis §4.1.5.1, figure 4.8): the target
 * clipped in place to [lo, hi] (the min/max counts once homed; None before), vel = target -
 * previous [counts/tick], the following error target - pos [counts] checked against fe_max
 * (None: a following-error fault, the caller stops), then the PID and round().  int64 arrays
 * of six; fe_max float64; gains/state as pid_step.  Integer arithmetic is exact as Python's
 * for |counts| < 2^62; the error limit is compared as Python compares an int with a float. */
static PyObject *servo_tail(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 10) {
        PyErr_SetString(PyExc_TypeError, "servo_tail takes 10 arguments");
        return NULL;
    }
    Bufs bs = {.n = 0};
    int64_t *target = get(&bs, args[0], N * 8, 1, "target");
    const int64_t *previous = target ? get(&bs, args[1], N * 8, 0, "previous") : NULL;
    const int64_t *lo = NULL, *hi = NULL;
    int ok = previous != NULL;
    if (ok && args[2] != Py_None) {
        lo = get(&bs, args[2], N * 8, 0, "lo");
        hi = lo ? get(&bs, args[3], N * 8, 0, "hi") : NULL;
        ok = hi != NULL;
    }
    const int64_t *pos = ok ? get(&bs, args[4], N * 8, 0, "pos") : NULL;
    const double *fe_max = pos ? get(&bs, args[5], N * 8, 0, "fe_max") : NULL;
    int64_t *vel = fe_max ? get(&bs, args[6], N * 8, 1, "vel") : NULL;
    const double *g = vel ? get(&bs, args[7], 5 * N * 8, 0, "gains") : NULL;
    double *st = g ? get(&bs, args[8], 2 * N * 8, 1, "state") : NULL;
    int first = st ? PyObject_IsTrue(args[9]) : -1;
    if (first < 0) {
        release(&bs);
        return NULL;
    }
    double e_now[N];
    int fault = 0;
    for (int j = 0; j < N; j++) {
        int64_t t = target[j];
        if (lo != NULL) {  /* np.minimum(np.maximum(target, lo), hi) */
            t = t > lo[j] ? t : lo[j];
            t = t < hi[j] ? t : hi[j];
            target[j] = t;
        }
        vel[j] = t - previous[j];
        int64_t e = t - pos[j];
        long double el = (long double)e, lim = (long double)fe_max[j];  /* exact: 64-bit mantissa */
        if (el > lim || -el > lim)
            fault = 1;
        e_now[j] = (double)e;  /* float(e): round to nearest */
    }
    if (fault) {
        release(&bs);
        Py_RETURN_NONE;
    }
    PyObject *out = pid_run(g, st, N, first, e_now, 1);
    release(&bs);
    return out;
}

/* exact_checks(q, lin_q, relin_rad, stop_mid, stop_lim) -> 0, 1 or 2
 * The exact step's two guards (ReisPlant._near_stop and _discretise's test), the same comparisons:
 * 2 if a link could reach a hard stop within the step (|q - mid| >= lim: the substep integrator
 * takes the advance), else 1 if a joint moved more than relin_rad from the linearisation lin_q
 * (None: none yet), else 0.  Float64 arrays of six [rad]. */
static PyObject *exact_checks(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 5) {
        PyErr_SetString(PyExc_TypeError, "exact_checks takes 5 arguments");
        return NULL;
    }
    double r = PyFloat_AsDouble(args[2]);
    if (r == -1.0 && PyErr_Occurred())
        return NULL;
    Bufs bs = {.n = 0};
    const double *q = get(&bs, args[0], N * 8, 0, "q");
    const double *lin = NULL;
    int ok = q != NULL;
    if (ok && args[1] != Py_None)
        ok = (lin = get(&bs, args[1], N * 8, 0, "lin_q")) != NULL;
    const double *mid = ok ? get(&bs, args[3], N * 8, 0, "stop_mid") : NULL;
    const double *lim = mid ? get(&bs, args[4], N * 8, 0, "stop_lim") : NULL;
    if (lim == NULL) {
        release(&bs);
        return NULL;
    }
    long code = 0;
    for (int j = 0; j < N; j++)
        if (fabs(q[j] - mid[j]) >= lim[j]) {
            code = 2;
            break;
        }
    if (code == 0) {
        if (lin == NULL)
            code = 1;
        else
            for (int j = 0; j < N; j++)
                if (fabs(q[j] - lin[j]) > r) {
                    code = 1;
                    break;
                }
    }
    release(&bs);
    return PyLong_FromLong(code);
}

static PyMethodDef methods[] = {
    {"set_gemv", set_gemv, METH_VARARGS, "set_gemv(address, int64): the cblas_dgemv to call (numpy's)"},
    {"exact_step", (PyCFunction)(void (*)(void))exact_step, METH_FASTCALL,
     "exact_step(regs, consts, pg, g_m, theta, omega, q, qd, tau_link, ext, amps_on, wd_fault, offset, x) "
     "-> encoders: the plant's exact zero-order-hold step (droid.sim.reis.plant)"},
    {"write_outputs", (PyCFunction)(void (*)(void))py_write_outputs, METH_FASTCALL,
     "write_outputs(regs, consts, theta, q, amps_on, wd_fault, offset) -> encoders"},
    {"matvec", (PyCFunction)(void (*)(void))py_matvec, METH_FASTCALL, "matvec(a, x, y): y = a @ x by the dgemv set"},
    {"pid_step", (PyCFunction)(void (*)(void))pid_step, METH_FASTCALL,
     "pid_step(gains, state, first, errors, rounded) -> outputs: droid.subunits.reis.pid.Pid.step"},
    {"extend_counters", (PyCFunction)(void (*)(void))extend_counters, METH_FASTCALL,
     "extend_counters(pos, raw, span, max_step, out) -> jumped: ServoCore._read_encoders"},
    {"exact_checks", (PyCFunction)(void (*)(void))exact_checks, METH_FASTCALL,
     "exact_checks(q, lin_q, relin_rad, stop_mid, stop_lim) -> 0, 1 (relinearise) or 2 (near a stop)"},
    {"servo_tail", (PyCFunction)(void (*)(void))servo_tail, METH_FASTCALL,
     "servo_tail(target, previous, lo, hi, pos, fe_max, vel, gains, state, first) -> dacs or None: ServoCore.step"},
    {"write_dacs", (PyCFunction)(void (*)(void))write_dacs, METH_FASTCALL,
     "write_dacs(regs, values) -> written or None: VmeBus.write_dacs for six ints"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "droid._kernel",
                                    "The compiled 500 Hz pair: the plant's exact step and the servo's PID.", -1,
                                    methods};

PyMODINIT_FUNC PyInit__kernel(void)
{
    PyObject *m = PyModule_Create(&module);
    if (m == NULL)
        return NULL;
    if (PyModule_AddIntConstant(m, "ENCODER_OFFSET", ENCODER_OFFSET) < 0 ||
        PyModule_AddIntConstant(m, "DAC_OFFSET", DAC_OFFSET) < 0 ||
        PyModule_AddIntConstant(m, "LIMIT_SWITCH_OFFSET", LIMIT_SWITCH_OFFSET) < 0 ||
        PyModule_AddIntConstant(m, "AMP_STATUS_OFFSET", AMP_STATUS_OFFSET) < 0 ||
        PyModule_AddIntConstant(m, "ENCODER_MODULUS", ENCODER_MODULUS) < 0 ||
        PyModule_AddIntConstant(m, "DAC_MIN", DAC_MIN) < 0 || PyModule_AddIntConstant(m, "DAC_MAX", DAC_MAX) < 0 ||
        PyModule_AddIntConstant(m, "AMP_STATUS_POWERED", AMP_STATUS_POWERED) < 0 ||
        PyModule_AddIntConstant(m, "AMP_STATUS_WATCHDOG_FAULT", AMP_STATUS_WATCHDOG_FAULT) < 0 ||
        PyModule_AddIntConstant(m, "C_LEN", C_LEN) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
