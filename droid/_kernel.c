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
 *
 * Also (rigid_steps, after rb_*): the plant's rigid-drive substeps (ReisPlant._steps_rigid,
 * droid-sim's world and the rigid lockstep cells) with the same rules, their 6x6 products through
 * the same dgemv, the solve through numpy's own LAPACK dgesv (set_gesv; droid/kernel.py finds and
 * checks it), the einsum's sums in numpy's order and numpy's maximum/minimum; an advance the
 * kernel cannot promise bit for bit (near a hard stop, a value not finite, a floating-point
 * exception numpy would act on) is handed back to the Python reference.
 *
 * Also (rb_*, at the end): a serial arm's rigid-body dynamics for droid-sim's world, in place of
 * Pinocchio there (droid.sim.reis.dynamics.RigidBody(backend="kernel")).  Those are tested
 * against Pinocchio to a tolerance, not bit for bit, and need no BLAS.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <fenv.h>
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
    Py_buffer b[16];
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
/* exact_step's arithmetic (see there) on plain pointers: the new state into x, the encoders written
   into enc; -1 with an exception set if a motor angle is not finite (write_outputs). */
static int exact_core(unsigned char *regs, const double *k, const double *pg, const double *gm,
                      const double *theta, const double *omega, const double *q, const double *qd,
                      const double *tl, const double *ext, int amps_on, int wd_fault, const int64_t *offset,
                      double *x, long enc[N])
{
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
    return write_outputs(regs, k, x, x + 12, offset, amps_on, wd_fault, enc);
}

static PyObject *exact_advance(PyObject *self, PyObject *const *args, Py_ssize_t nargs);

static PyObject *exact_step(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs == 18)  /* the guards, nle and the step in one call (exact_advance, below) */
        return exact_advance(self, args, nargs);
    if (nargs != 14) {
        PyErr_SetString(PyExc_TypeError, "exact_step takes 14 arguments (18: exact_advance's)");
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
    if (exact_core(regs, k, pg, gm, theta, omega, q, qd, tl, ext, amps_on, wd_fault, offset, x, enc) < 0) {
        release(&bs);
        return NULL;
    }
    release(&bs);
    return enc_tuple(enc);
}

/* exact_step(regs, consts, pg, g_m, theta, omega, q, qd, nle, ext, amps_on, wd_fault, offset, x,
 *            lin_q, relin_rad, stop_mid, stop_lim) -> encoders, or 1 or 2   (exact_advance)
 * ReisPlant._integrate's compiled exact branch in one call (issue 44): exact_checks' two guards
 * first -- 2 (near a hard stop) or 1 (relinearise: lin_q None or too far) is returned with nothing
 * called or changed, and the caller takes the Python path as before; else tau_link = nle(q, qd)
 * (the body's C(q, qd) qd + g, Pinocchio's call, made here with the very objects q and qd) and
 * exact_step with the discretisation pg, g_m at the current linearisation.  */
static PyObject *exact_advance(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 18) {
        PyErr_SetString(PyExc_TypeError, "exact_step's one-call form takes 18 arguments");
        return NULL;
    }
    if (gemv_fn == NULL) {
        PyErr_SetString(PyExc_RuntimeError, "droid._kernel: no BLAS dgemv set (droid.kernel sets it)");
        return NULL;
    }
    double r = PyFloat_AsDouble(args[15]);
    if (r == -1.0 && PyErr_Occurred())
        return NULL;
    Bufs bs = {.n = 0};
    long enc[N];
    const double *q = get(&bs, args[6], 6 * 8, 0, "q");
    const double *lin = NULL;
    int ok = q != NULL;
    if (ok && args[14] != Py_None)
        ok = (lin = get(&bs, args[14], N * 8, 0, "lin_q")) != NULL;
    const double *mid = ok ? get(&bs, args[16], N * 8, 0, "stop_mid") : NULL;
    const double *lim = mid ? get(&bs, args[17], N * 8, 0, "stop_lim") : NULL;
    if (lim == NULL) {
        release(&bs);
        return NULL;
    }
    long code = 0;  /* exact_checks */
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
    if (code != 0) {
        release(&bs);
        return PyLong_FromLong(code);
    }
    unsigned char *regs = get(&bs, args[0], -MAP_MIN_SIZE, 1, "regs");
    const double *k = regs ? get(&bs, args[1], C_LEN * 8, 0, "consts") : NULL;
    const double *pg = k ? get(&bs, args[2], 24 * 36 * 8, 0, "pg") : NULL;
    const double *gm = pg ? get(&bs, args[3], 24 * 6 * 8, 0, "g_m") : NULL;
    const double *theta = gm ? get(&bs, args[4], 6 * 8, 0, "theta") : NULL;
    const double *omega = theta ? get(&bs, args[5], 6 * 8, 0, "omega") : NULL;
    const double *qd = omega ? get(&bs, args[7], 6 * 8, 0, "qd") : NULL;
    const double *ext = NULL;
    ok = qd != NULL;
    if (ok && args[9] != Py_None)
        ok = (ext = get(&bs, args[9], 6 * 8, 0, "ext")) != NULL;
    int amps_on = ok ? PyObject_IsTrue(args[10]) : -1;
    int wd_fault = amps_on >= 0 ? PyObject_IsTrue(args[11]) : -1;
    const int64_t *offset = wd_fault >= 0 ? get(&bs, args[12], 6 * 8, 0, "offset") : NULL;
    double *x = offset ? get(&bs, args[13], 24 * 8, 1, "x") : NULL;
    if (x == NULL) {
        release(&bs);
        return NULL;
    }
    double tl[N];
    {
        PyObject *res = PyObject_CallFunctionObjArgs(args[8], args[6], args[7], NULL);
        if (res == NULL) {
            release(&bs);
            return NULL;
        }
        Py_buffer b;
        if (PyObject_GetBuffer(res, &b, PyBUF_C_CONTIGUOUS) < 0) {
            Py_DECREF(res);
            release(&bs);
            return NULL;
        }
        if (b.len != N * 8) {
            PyBuffer_Release(&b);
            Py_DECREF(res);
            release(&bs);
            PyErr_SetString(PyExc_ValueError, "exact_advance: nle must return six float64");
            return NULL;
        }
        memcpy(tl, b.buf, sizeof tl);
        PyBuffer_Release(&b);
        Py_DECREF(res);
    }
    if (exact_core(regs, k, pg, gm, theta, omega, q, qd, tl, ext, amps_on, wd_fault, offset, x, enc) < 0) {
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

/* servo_cycle(regs, pos, queue, qi, target, vel, lo, hi, fe_max, gains, state, first, span, max_step)
 *     -> (raw, dacs) or None
 * One whole servo tick of ServoStation.cycle on its common path (issue 44): the way-point queue
 * has a row left, no homing, no fault, one period.  The six 16-bit encoder registers read from
 * ``regs`` (VmeBus.read_encoders_raw), extended from ``pos`` as extend_counters does, the tick's
 * target = queue[qi] (CommandQueue.next_target's first branch), then servo_tail's clip, velocity,
 * following-error check and PID, and the DACs clamped and stored as write_dacs does.  None, with
 * nothing changed (no state, no register), where the tick leaves that path: an encoder jump or a
 * following error -- the caller then runs the Python reference, which takes the fault.  Else
 * ``pos``, ``target`` and ``vel`` (int64, six) are updated in place and the PID's state as
 * pid_step updates it; returns the encoder registers read and the DAC words (Python ints).  */
static PyObject *servo_cycle(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 14) {
        PyErr_SetString(PyExc_TypeError, "servo_cycle takes 14 arguments");
        return NULL;
    }
    Py_ssize_t qi = PyLong_AsSsize_t(args[3]);
    long long span = PyLong_AsLongLong(args[12]), jump = PyLong_AsLongLong(args[13]);
    if (PyErr_Occurred())
        return NULL;
    if (span <= 0 || span > (1LL << 32)) {
        PyErr_SetString(PyExc_ValueError, "servo_cycle: span out of range");
        return NULL;
    }
    Bufs bs = {.n = 0};
    unsigned char *regs = get(&bs, args[0], -MAP_MIN_SIZE, 1, "regs");
    int64_t *pos = regs ? get(&bs, args[1], N * 8, 1, "pos") : NULL;
    const int64_t *queue = pos ? get(&bs, args[2], -N * 8, 0, "queue") : NULL;
    int64_t *target = queue ? get(&bs, args[4], N * 8, 1, "target") : NULL;
    int64_t *vel = target ? get(&bs, args[5], N * 8, 1, "vel") : NULL;
    const int64_t *lo = NULL, *hi = NULL;
    int ok = vel != NULL;
    if (ok && args[6] != Py_None) {
        lo = get(&bs, args[6], N * 8, 0, "lo");
        hi = lo ? get(&bs, args[7], N * 8, 0, "hi") : NULL;
        ok = hi != NULL;
    }
    const double *fe_max = ok ? get(&bs, args[8], N * 8, 0, "fe_max") : NULL;
    const double *g = fe_max ? get(&bs, args[9], 5 * N * 8, 0, "gains") : NULL;
    double *st = g ? get(&bs, args[10], 2 * N * 8, 1, "state") : NULL;
    int first = st ? PyObject_IsTrue(args[11]) : -1;
    if (first < 0) {
        release(&bs);
        return NULL;
    }
    Py_ssize_t rows = bs.b[2].len / (N * 8);
    if (bs.b[2].len % (N * 8) || qi < 0 || qi >= rows) {
        release(&bs);
        PyErr_SetString(PyExc_ValueError, "servo_cycle: queue (n, 6) int64 with 0 <= qi < n");
        return NULL;
    }
    long raw[N];
    int64_t newpos[N], t[N], v[N];
    double e_now[N];
    long long half = span >> 1;
    const int64_t *row = queue + qi * N;
    for (int j = 0; j < N; j++) {
        const unsigned char *p = regs + ENCODER_OFFSET + 2 * j;
        raw[j] = (long)(p[0] | (p[1] << 8));
        long long delta = ((long long)raw[j] - pos[j]) % span;  /* ServoCore._read_encoders */
        if (delta < 0)
            delta += span;
        if (delta >= half)
            delta -= span;
        if (delta > jump || -delta > jump) {  /* an encoder jump: the reference takes the fault */
            release(&bs);
            Py_RETURN_NONE;
        }
        newpos[j] = pos[j] + delta;
        int64_t tj = row[j];
        if (lo != NULL) {  /* servo_tail from here on */
            tj = tj > lo[j] ? tj : lo[j];
            tj = tj < hi[j] ? tj : hi[j];
        }
        t[j] = tj;
        v[j] = tj - target[j];
        int64_t e = tj - newpos[j];
        long double el = (long double)e, lim = (long double)fe_max[j];
        if (el > lim || -el > lim) {  /* a following error: the reference takes the fault */
            release(&bs);
            Py_RETURN_NONE;
        }
        e_now[j] = (double)e;
    }
    PyObject *dacs = pid_run(g, st, N, first, e_now, 1);
    if (dacs == NULL) {
        release(&bs);
        return NULL;
    }
    long d[N];
    for (int j = 0; j < N; j++) {
        int overflow = 0;
        long long x = PyLong_AsLongLongAndOverflow(PyTuple_GET_ITEM(dacs, j), &overflow);
        if (overflow)
            x = overflow > 0 ? DAC_MAX : DAC_MIN;
        d[j] = x < DAC_MIN ? DAC_MIN : (x > DAC_MAX ? DAC_MAX : (long)x);
    }
    for (int j = 0; j < N; j++) {
        pos[j] = newpos[j];
        target[j] = t[j];
        vel[j] = v[j];
        wr_u16(regs + DAC_OFFSET + 2 * j, (unsigned)(uint16_t)(int16_t)d[j]);
    }
    release(&bs);
    PyObject *rawt = enc_tuple(raw);
    if (rawt == NULL) {
        Py_DECREF(dacs);
        return NULL;
    }
    PyObject *out = PyTuple_Pack(2, rawt, dacs);
    Py_DECREF(rawt);
    Py_DECREF(dacs);
    return out;
}

/* servo_status(tick, mode, homing_joint, starved, braking, fault, amps_on, pos, target, zero, dac)
 *     -> bytes or None
 * ServoCore.status_message's bytes (servo_wire.pack_status_values, ``<4s Q 7i 6i 6i 6i 6h``: b"DSS2",
 * the tick, mode, homed (zero given), homing joint, starved, braking, fault, amplifiers, then
 * encoder_pos, encoder_cmd, following_error -- home-relative once homed, each clipped to int32 --
 * and the DACs) from the core's int64 arrays ``pos``, ``target`` and ``zero`` (None before homing)
 * and its six DAC ints.  None where the reference must decide (a difference beyond int64, a DAC
 * beyond int16, a scalar beyond its field): the caller packs it in Python (which raises there).  */
static PyObject *servo_status(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 11) {
        PyErr_SetString(PyExc_TypeError, "servo_status takes 11 arguments");
        return NULL;
    }
    int overflow = 0;
    unsigned long long tick = PyLong_AsUnsignedLongLong(args[0]);
    if (tick == (unsigned long long)-1 && PyErr_Occurred()) {
        PyErr_Clear();
        Py_RETURN_NONE;
    }
    long long sc[6];
    for (int i = 0; i < 6; i++) {
        sc[i] = PyLong_AsLongLongAndOverflow(args[1 + i], &overflow);
        if (overflow || sc[i] < INT32_MIN || sc[i] > INT32_MAX)
            Py_RETURN_NONE;
        if (sc[i] == -1 && PyErr_Occurred())
            return NULL;
    }
    PyObject *dac = args[10];
    if (!PyTuple_CheckExact(dac) || PyTuple_GET_SIZE(dac) != N)
        Py_RETURN_NONE;
    long long d[N];
    for (int j = 0; j < N; j++) {
        PyObject *o = PyTuple_GET_ITEM(dac, j);
        if (!PyLong_CheckExact(o))
            Py_RETURN_NONE;
        d[j] = PyLong_AsLongLongAndOverflow(o, &overflow);
        if (overflow || d[j] < INT16_MIN || d[j] > INT16_MAX)
            Py_RETURN_NONE;
    }
    Bufs bs = {.n = 0};
    const int64_t *pos = get(&bs, args[7], N * 8, 0, "pos");
    const int64_t *target = pos ? get(&bs, args[8], N * 8, 0, "target") : NULL;
    const int64_t *zero = NULL;
    if (target && args[9] != Py_None && (zero = get(&bs, args[9], N * 8, 0, "zero")) == NULL)
        target = NULL;
    if (target == NULL) {
        release(&bs);
        return NULL;
    }
    long long counts[3 * N];
    for (int j = 0; j < N; j++) {
        long long p = pos[j], t = target[j], fe;
        if (__builtin_sub_overflow(t, p, &fe)) {
            release(&bs);
            Py_RETURN_NONE;
        }
        if (zero != NULL && (__builtin_sub_overflow(t, (long long)zero[j], &t) ||
                             __builtin_sub_overflow(p, (long long)zero[j], &p))) {
            release(&bs);
            Py_RETURN_NONE;
        }
        counts[j] = p;
        counts[N + j] = t;
        counts[2 * N + j] = fe;
    }
    release(&bs);
    unsigned char b[124], *w = b;
    memcpy(w, "DSS2", 4);
    w += 4;
    for (int i = 0; i < 8; i++)
        *w++ = (unsigned char)(tick >> (8 * i));
    long long fields[7] = {sc[0], zero != NULL, sc[1], sc[2], sc[3], sc[4], sc[5]};
    for (int i = 0; i < 7 + 3 * N; i++) {
        long long v = i < 7 ? fields[i] : counts[i - 7];
        if (v < INT32_MIN)  /* pack_status_values' clip of the 18 counts */
            v = INT32_MIN;
        if (v > INT32_MAX)
            v = INT32_MAX;
        uint32_t u = (uint32_t)(int32_t)v;
        for (int k = 0; k < 4; k++)
            *w++ = (unsigned char)(u >> (8 * k));
    }
    for (int j = 0; j < N; j++) {
        uint16_t u = (uint16_t)(int16_t)d[j];
        *w++ = (unsigned char)(u & 0xFF);
        *w++ = (unsigned char)(u >> 8);
    }
    return PyBytes_FromStringAndSize((const char *)b, (Py_ssize_t)(w - b));
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

/* -- rigid-body dynamics of a serial chain of revolute joints (droid.sim.reis.dynamics) ---------- */
/* Featherstone's recursive Newton-Euler (RNEA) and composite-rigid-body (CRBA) algorithms for an
 * open chain of n revolute joints, each turning about the z axis of its own frame, joint i the
 * child of joint i-1 (joint 0 the child of the base), as Pinocchio models the arm (JointModelRZ;
 * droid.sim.reis.dynamics.build_model): droid-sim's world uses these instead of importing
 * Pinocchio (its ~48 MB).  Not bit-identical to Pinocchio (other operation order), tested against
 * it (tests/sim/test_rigid_body_kernel.py).
 *
 * The model, one float64 buffer of 25 n + 3 values [SI: m, kg, kg m^2, m/s^2]: per joint, its
 * placement in its parent's frame at q = 0 (rotation 3x3 row-major, translation 3), then its
 * link's mass, centre of mass (3, joint frame) and inertia about the centre of mass (3x3, joint
 * frame); after the joints, the gravity vector in the base frame (Pinocchio's model.gravity, e.g.
 * (0, 0, -9.81)).  Spatial vectors are Pinocchio's: motion (v, w), force (f, n), in joint frames. */
#define RB_MAXJ 16
#define RB_PER_JOINT 25

typedef struct {
    int n;
    const double *m;  /* the model buffer */
    double R[RB_MAXJ][9];  /* joint i's frame in its parent's at q: placement rotation * Rz(q_i) */
    double p[RB_MAXJ][3];
} RbChain;

/* the model buffer (checked: 25 n + 3 float64, 1 <= n <= RB_MAXJ) -> n, or -1 with ValueError */
static int rb_joints(Py_ssize_t bytes)
{
    Py_ssize_t vals = bytes / 8;
    if (bytes % 8 == 0 && vals > 3 && (vals - 3) % RB_PER_JOINT == 0 && (vals - 3) / RB_PER_JOINT <= RB_MAXJ)
        return (int)((vals - 3) / RB_PER_JOINT);
    PyErr_Format(PyExc_ValueError, "model: %zd bytes, need 8 * (25 n + 3) for n joints, 1 <= n <= %d "
                 "(per joint: placement rotation 9, translation 3, mass 1, com 3, inertia 9; then gravity 3)",
                 bytes, RB_MAXJ);
    return -1;
}

/* the joints' frames at q: R_i = Rp_i Rz(q_i), p_i = pp_i */
static void rb_frames(RbChain *c, const double *q)
{
    for (int i = 0; i < c->n; i++) {
        const double *J = c->m + RB_PER_JOINT * i;
        double cq = cos(q[i]), sq = sin(q[i]);
        for (int r = 0; r < 3; r++) {
            double a = J[3 * r], b = J[3 * r + 1];
            c->R[i][3 * r] = a * cq + b * sq;
            c->R[i][3 * r + 1] = b * cq - a * sq;
            c->R[i][3 * r + 2] = J[3 * r + 2];
        }
        c->p[i][0] = J[9];
        c->p[i][1] = J[10];
        c->p[i][2] = J[11];
    }
}

static inline void cross3(const double *a, const double *b, double *o)
{
    double x = a[1] * b[2] - a[2] * b[1], y = a[2] * b[0] - a[0] * b[2], z = a[0] * b[1] - a[1] * b[0];
    o[0] = x;
    o[1] = y;
    o[2] = z;
}

static inline void mulT3(const double *R, const double *x, double *o)  /* o = R^T x */
{
    double a = R[0] * x[0] + R[3] * x[1] + R[6] * x[2];
    double b = R[1] * x[0] + R[4] * x[1] + R[7] * x[2];
    double c = R[2] * x[0] + R[5] * x[1] + R[8] * x[2];
    o[0] = a;
    o[1] = b;
    o[2] = c;
}

static inline void mul3(const double *R, const double *x, double *o)  /* o = R x */
{
    double a = R[0] * x[0] + R[1] * x[1] + R[2] * x[2];
    double b = R[3] * x[0] + R[4] * x[1] + R[5] * x[2];
    double c = R[6] * x[0] + R[7] * x[1] + R[8] * x[2];
    o[0] = a;
    o[1] = b;
    o[2] = c;
}

/* motion (v, w) in the parent's frame -> in the child's (frame R, p): w' = R^T w, v' = R^T (v - p x w) */
static void rb_motion_inv(const double *R, const double *p, const double *m, double *o)
{
    double t[3];
    cross3(p, m + 3, t);
    t[0] = m[0] - t[0];
    t[1] = m[1] - t[1];
    t[2] = m[2] - t[2];
    mulT3(R, m + 3, o + 3);
    mulT3(R, t, o);
}

/* force (f, n) in the child's frame (R, p) -> in the parent's: f' = R f, n' = R n + p x f' */
static void rb_force_act(const double *R, const double *p, const double *f, double *o)
{
    double t[3];
    mul3(R, f, o);
    mul3(R, f + 3, o + 3);
    cross3(p, o, t);
    o[3] += t[0];
    o[4] += t[1];
    o[5] += t[2];
}

/* the link's spatial inertia times a motion, at the joint frame's origin: h = m (v + w x c),
   n = I_c w + c x h */
static void rb_inertia_mul(const double *J, const double *mv, double *o)
{
    double mass = J[12];
    const double *c = J + 13, *I = J + 16;
    double t[3];
    cross3(mv + 3, c, t);
    o[0] = mass * (mv[0] + t[0]);
    o[1] = mass * (mv[1] + t[1]);
    o[2] = mass * (mv[2] + t[2]);
    mul3(I, mv + 3, o + 3);
    cross3(c, o, t);
    o[3] += t[0];
    o[4] += t[1];
    o[5] += t[2];
}

/* RNEA: tau = M(q) qdd + C(q, qd) qd + g(q) [N m]; qd, qdd NULL: zero; gravity: 0 leaves it out */
static void rb_rnea(RbChain *c, const double *qd, const double *qdd, int gravity, double *tau)
{
    int n = c->n;
    double v[RB_MAXJ][6], a[RB_MAXJ][6], f[RB_MAXJ][6];
    const double *g = c->m + RB_PER_JOINT * n;
    double v0[6] = {0, 0, 0, 0, 0, 0}, a0[6] = {0, 0, 0, 0, 0, 0};
    if (gravity) {  /* the base accelerates up at g: a_0 = -gravity */
        a0[0] = -g[0];
        a0[1] = -g[1];
        a0[2] = -g[2];
    }
    for (int i = 0; i < n; i++) {
        const double *vp = i ? v[i - 1] : v0, *ap = i ? a[i - 1] : a0;
        double w = qd ? qd[i] : 0.0;
        rb_motion_inv(c->R[i], c->p[i], vp, v[i]);
        rb_motion_inv(c->R[i], c->p[i], ap, a[i]);
        /* + S qdd + v x (S qd), S = (0, 0, 0, 0, 0, 1): (v x e_z w, w x e_z w) */
        a[i][0] += v[i][1] * w;
        a[i][1] -= v[i][0] * w;
        a[i][3] += v[i][4] * w;
        a[i][4] -= v[i][3] * w;
        a[i][5] += qdd ? qdd[i] : 0.0;
        v[i][5] += w;
        /* f = I a + v x* (I v); v x* h = (w x h_f, w x h_n + v x h_f) */
        const double *J = c->m + RB_PER_JOINT * i;
        double h[6], t[3], s[3];
        rb_inertia_mul(J, a[i], f[i]);
        rb_inertia_mul(J, v[i], h);
        cross3(v[i] + 3, h, t);
        f[i][0] += t[0];
        f[i][1] += t[1];
        f[i][2] += t[2];
        cross3(v[i] + 3, h + 3, t);
        cross3(v[i], h, s);
        f[i][3] += t[0] + s[0];
        f[i][4] += t[1] + s[1];
        f[i][5] += t[2] + s[2];
    }
    for (int i = n - 1; i >= 0; i--) {
        tau[i] = f[i][5];
        if (i > 0) {
            double o[6];
            rb_force_act(c->R[i], c->p[i], f[i], o);
            for (int k = 0; k < 6; k++)
                f[i - 1][k] += o[k];
        }
    }
}

/* CRBA: the joint-space mass matrix M(q) [kg m^2], full and symmetric, row-major n x n */
static void rb_crba(RbChain *c, double *M)
{
    int n = c->n;
    double Ic[RB_MAXJ][6][6];
    for (int i = 0; i < n; i++) {  /* each link's spatial inertia at its joint frame (columns: I e_k) */
        const double *J = c->m + RB_PER_JOINT * i;
        for (int k = 0; k < 6; k++) {
            double e[6] = {0, 0, 0, 0, 0, 0}, col[6];
            e[k] = 1.0;
            rb_inertia_mul(J, e, col);
            for (int r = 0; r < 6; r++)
                Ic[i][r][k] = col[r];
        }
    }
    for (int i = n - 1; i > 0; i--) {  /* composite: Ic_parent += X* Ic X*^T */
        double T[6][6];  /* T = X* Ic: each column a force moved to the parent */
        for (int k = 0; k < 6; k++) {
            double col[6], o[6];
            for (int r = 0; r < 6; r++)
                col[r] = Ic[i][r][k];
            rb_force_act(c->R[i], c->p[i], col, o);
            for (int r = 0; r < 6; r++)
                T[r][k] = o[r];
        }
        for (int r = 0; r < 6; r++) {  /* (X* T^T)^T = T X*^T: X* of each row of T */
            double o[6];
            rb_force_act(c->R[i], c->p[i], T[r], o);
            for (int k = 0; k < 6; k++)
                Ic[i - 1][r][k] += o[k];
        }
    }
    for (int i = 0; i < n; i++) {
        double F[6];
        for (int r = 0; r < 6; r++)
            F[r] = Ic[i][r][5];  /* Ic S */
        M[i * n + i] = F[5];
        for (int j = i; j > 0; j--) {
            double o[6];
            rb_force_act(c->R[j], c->p[j], F, o);
            memcpy(F, o, sizeof F);
            M[(j - 1) * n + i] = M[i * n + j - 1] = F[5];
        }
    }
}

/* Cholesky factor L (lower, row-major) of the n x n M in place; -1 with ValueError if M is not
   positive definite */
static int rb_cholesky(double *M, int n)
{
    for (int j = 0; j < n; j++) {
        double d = M[j * n + j];
        for (int k = 0; k < j; k++)
            d -= M[j * n + k] * M[j * n + k];
        if (!(d > 0.0)) {
            PyErr_SetString(PyExc_ValueError, "the mass matrix is not positive definite (a bad model?)");
            return -1;
        }
        d = sqrt(d);
        M[j * n + j] = d;
        for (int i = j + 1; i < n; i++) {
            double s = M[i * n + j];
            for (int k = 0; k < j; k++)
                s -= M[i * n + k] * M[j * n + k];
            M[i * n + j] = s / d;
        }
    }
    return 0;
}

/* x = (L L^T)^-1 b in place */
static void rb_chol_solve(const double *L, int n, double *x)
{
    for (int i = 0; i < n; i++) {
        double s = x[i];
        for (int k = 0; k < i; k++)
            s -= L[i * n + k] * x[k];
        x[i] = s / L[i * n + i];
    }
    for (int i = n - 1; i >= 0; i--) {
        double s = x[i];
        for (int k = i + 1; k < n; k++)
            s -= L[k * n + i] * x[k];
        x[i] = s / L[i * n + i];
    }
}

/* the world placement of each joint's frame (rotation 3x3, origin 3) [m] */
static void rb_world(RbChain *c, double oR[][9], double op[][3])
{
    for (int i = 0; i < c->n; i++) {
        if (i == 0) {
            memcpy(oR[0], c->R[0], sizeof oR[0]);
            memcpy(op[0], c->p[0], sizeof op[0]);
            continue;
        }
        for (int r = 0; r < 3; r++)
            for (int k = 0; k < 3; k++)
                oR[i][3 * r + k] = oR[i - 1][3 * r] * c->R[i][k] + oR[i - 1][3 * r + 1] * c->R[i][3 + k] +
                                   oR[i - 1][3 * r + 2] * c->R[i][6 + k];
        mul3(oR[i - 1], c->p[i], op[i]);
        for (int k = 0; k < 3; k++)
            op[i][k] += op[i - 1][k];
    }
}

/* the arguments every rb_ function starts with: (model, q); returns n or -1 */
static int rb_begin(RbChain *c, Bufs *bs, PyObject *model, PyObject *q_obj, const double **q, const char *name,
                    Py_ssize_t nargs, Py_ssize_t want)
{
    if (nargs != want) {
        PyErr_Format(PyExc_TypeError, "%s takes %zd arguments (%zd given)", name, want, nargs);
        return -1;
    }
    c->m = get(bs, model, -8, 0, "model");
    if (c->m == NULL)
        return -1;
    c->n = rb_joints(bs->b[bs->n - 1].len);
    if (c->n < 0)
        return -1;
    *q = get(bs, q_obj, c->n * 8, 0, "q");
    if (*q == NULL)
        return -1;
    rb_frames(c, *q);
    return c->n;
}

/* rb_rnea(model, q, qd, qdd, gravity, tau): tau = M qdd + C qd + g [N m]; qd, qdd None: zero
   (qdd None: Pinocchio's nonLinearEffects; both: its computeGeneralizedGravity) */
static PyObject *py_rb_rnea(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    RbChain c;
    Bufs bs = {.n = 0};
    const double *q, *qd = NULL, *qdd = NULL;
    double *tau = NULL;
    int n = rb_begin(&c, &bs, nargs > 0 ? args[0] : NULL, nargs > 1 ? args[1] : NULL, &q, "rb_rnea", nargs, 6);
    int ok = n > 0;
    if (ok && args[2] != Py_None)
        ok = (qd = get(&bs, args[2], n * 8, 0, "qd")) != NULL;
    if (ok && args[3] != Py_None)
        ok = (qdd = get(&bs, args[3], n * 8, 0, "qdd")) != NULL;
    int gravity = ok ? PyObject_IsTrue(args[4]) : 0;
    if (gravity < 0)
        ok = 0;
    if (ok)
        ok = (tau = get(&bs, args[5], n * 8, 1, "tau")) != NULL;
    if (ok)
        rb_rnea(&c, qd, qdd, gravity, tau);
    release(&bs);
    if (!ok)
        return NULL;
    Py_RETURN_NONE;
}

/* rb_crba(model, q, M): the mass matrix [kg m^2] into M (n x n, full) */
static PyObject *py_rb_crba(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    RbChain c;
    Bufs bs = {.n = 0};
    const double *q;
    double *M = NULL;
    int n = rb_begin(&c, &bs, nargs > 0 ? args[0] : NULL, nargs > 1 ? args[1] : NULL, &q, "rb_crba", nargs, 3);
    if (n > 0 && (M = get(&bs, args[2], (Py_ssize_t)n * n * 8, 1, "M")) != NULL)
        rb_crba(&c, M);
    release(&bs);
    if (M == NULL)
        return NULL;
    Py_RETURN_NONE;
}

/* rb_minv(model, q, Minv): M(q)^-1 [1/(kg m^2)] into Minv (n x n, full), by Cholesky */
static PyObject *py_rb_minv(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    RbChain c;
    Bufs bs = {.n = 0};
    const double *q;
    double *out = NULL, M[RB_MAXJ * RB_MAXJ];
    int n = rb_begin(&c, &bs, nargs > 0 ? args[0] : NULL, nargs > 1 ? args[1] : NULL, &q, "rb_minv", nargs, 3);
    int ok = n > 0 && (out = get(&bs, args[2], (Py_ssize_t)n * n * 8, 1, "Minv")) != NULL;
    if (ok) {
        rb_crba(&c, M);
        ok = rb_cholesky(M, n) == 0;
    }
    if (ok) {
        for (int k = 0; k < n; k++) {
            double x[RB_MAXJ];
            for (int i = 0; i < n; i++)
                x[i] = i == k ? 1.0 : 0.0;
            rb_chol_solve(M, n, x);
            for (int i = 0; i < n; i++)
                out[i * n + k] = x[i];
        }
        for (int i = 0; i < n; i++)  /* exactly symmetric: the upper triangle mirrored */
            for (int k = 0; k < i; k++)
                out[i * n + k] = out[k * n + i];
    }
    release(&bs);
    if (!ok)
        return NULL;
    Py_RETURN_NONE;
}

/* rb_aba(model, q, qd, tau, qdd): forward dynamics qdd = M^-1 (tau - C qd - g) [rad/s^2] */
static PyObject *py_rb_aba(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    RbChain c;
    Bufs bs = {.n = 0};
    const double *q, *qd = NULL, *tau = NULL;
    double *qdd = NULL, M[RB_MAXJ * RB_MAXJ];
    int n = rb_begin(&c, &bs, nargs > 0 ? args[0] : NULL, nargs > 1 ? args[1] : NULL, &q, "rb_aba", nargs, 5);
    int ok = n > 0 && (qd = get(&bs, args[2], n * 8, 0, "qd")) != NULL &&
             (tau = get(&bs, args[3], n * 8, 0, "tau")) != NULL && (qdd = get(&bs, args[4], n * 8, 1, "qdd")) != NULL;
    if (ok) {
        double nle[RB_MAXJ];
        rb_rnea(&c, qd, NULL, 1, nle);
        rb_crba(&c, M);
        ok = rb_cholesky(M, n) == 0;
        if (ok) {
            double x[RB_MAXJ];
            for (int i = 0; i < n; i++)
                x[i] = tau[i] - nle[i];
            rb_chol_solve(M, n, x);
            memcpy(qdd, x, n * sizeof(double));
        }
    }
    release(&bs);
    if (!ok)
        return NULL;
    Py_RETURN_NONE;
}

/* rb_jacobian(model, q, J, oM): the last joint's placement in the base frame (4x4 [m]) into oM and,
   if J is not None, its 6 x n Jacobian in Pinocchio's LOCAL_WORLD_ALIGNED convention (rows v, w:
   the velocity of the last joint frame's origin and the angular velocity, base axes [m/rad, 1]) */
static PyObject *py_rb_jacobian(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    RbChain c;
    Bufs bs = {.n = 0};
    const double *q;
    double *J = NULL, *oM = NULL;
    int n = rb_begin(&c, &bs, nargs > 0 ? args[0] : NULL, nargs > 1 ? args[1] : NULL, &q, "rb_jacobian", nargs, 4);
    int ok = n > 0 && (args[2] == Py_None || (J = get(&bs, args[2], (Py_ssize_t)6 * n * 8, 1, "J")) != NULL) &&
             (oM = get(&bs, args[3], 16 * 8, 1, "oM")) != NULL;
    if (ok) {
        double oR[RB_MAXJ][9], op[RB_MAXJ][3];
        rb_world(&c, oR, op);
        const double *Re = oR[n - 1], *pe = op[n - 1];
        for (int r = 0; r < 3; r++) {
            oM[4 * r] = Re[3 * r];
            oM[4 * r + 1] = Re[3 * r + 1];
            oM[4 * r + 2] = Re[3 * r + 2];
            oM[4 * r + 3] = pe[r];
        }
        oM[12] = oM[13] = oM[14] = 0.0;
        oM[15] = 1.0;
        for (int k = 0; J != NULL && k < n; k++) {  /* column k: (z_k x (p_e - p_k), z_k) */
            double z[3] = {oR[k][2], oR[k][5], oR[k][8]}, d[3], v[3];
            d[0] = pe[0] - op[k][0];
            d[1] = pe[1] - op[k][1];
            d[2] = pe[2] - op[k][2];
            cross3(z, d, v);
            for (int r = 0; r < 3; r++) {
                J[r * n + k] = v[r];
                J[(r + 3) * n + k] = z[r];
            }
        }
    }
    release(&bs);
    if (!ok)
        return NULL;
    Py_RETURN_NONE;
}


/* -- the plant's rigid-drive substeps (ReisPlant._steps_rigid; droid/sim/reis/plant.py) ----------- */
/* numpy's LAPACK dgesv, the routine numpy.linalg.solve's gufunc (_umath_linalg.solve1) calls: its
 * bundled OpenBLAS (scipy_dgesv_64_), found and checked bit for bit against np.linalg.solve by
 * droid/kernel.py.  Fortran interface, 64-bit or 32-bit ints. */
typedef void (*dgesv64_t)(const int64_t *, const int64_t *, double *, const int64_t *, int64_t *, double *,
                          const int64_t *, int64_t *);
typedef void (*dgesv32_t)(const int32_t *, const int32_t *, double *, const int32_t *, int32_t *, double *,
                          const int32_t *, int32_t *);
static void *gesv_fn = NULL;
static int gesv_int64 = 1;

static PyObject *set_gesv(PyObject *self, PyObject *args)
{
    unsigned long long addr;
    int int64;
    if (!PyArg_ParseTuple(args, "Kp", &addr, &int64))
        return NULL;
    gesv_fn = (void *)(uintptr_t)addr;
    gesv_int64 = int64;
    Py_RETURN_NONE;
}

/* x = a^-1 b for a C-contiguous n x n a as numpy's solve1 computes it: a copied in Fortran order
 * (numpy's linearize_matrix), b copied, dgesv with one right-hand side (lda = ldb = n).  Returns
 * LAPACK's info: 0 solved, > 0 singular (numpy then returns NaNs and flags 'invalid'). */
static long gesv(const double *a, int n, const double *b, double *x)
{
    double f[RB_MAXJ * RB_MAXJ];
    for (int r = 0; r < n; r++)
        for (int c = 0; c < n; c++)
            f[c * n + r] = a[r * n + c];
    memcpy(x, b, n * sizeof(double));
    if (gesv_int64) {
        int64_t nn = n, one = 1, info = 0, ipiv[RB_MAXJ];
        ((dgesv64_t)gesv_fn)(&nn, &one, f, &nn, ipiv, x, &nn, &info);
        return (long)info;
    }
    int32_t nn = n, one = 1, info = 0, ipiv[RB_MAXJ];
    ((dgesv32_t)gesv_fn)(&nn, &one, f, &nn, ipiv, x, &nn, &info);
    return (long)info;
}

/* solve(a, b, x) -> info: x = a^-1 b through the dgesv set (for droid/kernel.py's bit check) */
static PyObject *py_solve(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 3) {
        PyErr_SetString(PyExc_TypeError, "solve takes 3 arguments");
        return NULL;
    }
    if (gesv_fn == NULL) {
        PyErr_SetString(PyExc_RuntimeError, "droid._kernel: no LAPACK dgesv set");
        return NULL;
    }
    Bufs bs = {.n = 0};
    const double *b = get(&bs, args[1], -8, 0, "b");
    Py_ssize_t n = b ? bs.b[0].len / 8 : 0;
    const double *a = b ? get(&bs, args[0], n * n * 8, 0, "a") : NULL;
    double *x = a ? get(&bs, args[2], n * 8, 1, "x") : NULL;
    if (x != NULL && n > RB_MAXJ) {
        PyErr_Format(PyExc_ValueError, "solve: n = %zd > %d", n, RB_MAXJ);
        x = NULL;
    }
    long info = x ? gesv(a, (int)n, b, x) : 0;
    release(&bs);
    return x ? PyLong_FromLong(info) : NULL;
}

/* numpy's maximum and minimum for float64 (NaN propagates, the first argument's first).  Where
 * both are zeros of opposite signs numpy's answer depends on its SIMD path (its scalar loop
 * returns the first, its vector loops the second): *amb is set and the caller lets the Python
 * reference take the advance. */
static inline double np_maximum(double a, double b, int *amb)
{
    if (isnan(a))
        return a;
    if (isnan(b))
        return b;
    if (a == b) {
        if (signbit(a) != signbit(b))
            *amb = 1;
        return a;
    }
    return a > b ? a : b;
}

static inline double np_minimum(double a, double b, int *amb)
{
    if (isnan(a))
        return a;
    if (isnan(b))
        return b;
    if (a == b) {
        if (signbit(a) != signbit(b))
            *amb = 1;
        return a;
    }
    return a < b ? a : b;
}

/* out (len doubles) = obj's buffer (a 1-D or 2-D float64 C-contiguous array, Python's answer) */
static int copy_answer(PyObject *obj, double *out, Py_ssize_t len, const char *what)
{
    if (obj == NULL)
        return -1;
    Py_buffer b;
    int r = PyObject_GetBuffer(obj, &b, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT);
    Py_DECREF(obj);
    if (r < 0)
        return -1;
    if (b.len != len * 8 || b.itemsize != 8 || b.format == NULL || strcmp(b.format, "d") != 0) {
        PyErr_Format(PyExc_ValueError, "%s: the body's answer is not %zd float64", what, len);
        PyBuffer_Release(&b);
        return -1;
    }
    memcpy(out, b.buf, len * 8);
    PyBuffer_Release(&b);
    return 0;
}

/* the rigid-drive constants, one float64 vector (ReisPlant._rigid_consts) */
enum { R_A = 0, R_AINVT = 36, R_AINV = 72, R_JROT = 108, R_B = 144, R_W0 = 150, R_LEN = 156 };
#define FP_BAD (FE_INVALID | FE_DIVBYZERO | FE_OVERFLOW | FE_UNDERFLOW)

/* rigid_steps(regs, consts, rigid, model, mass, nle, qbuf, qdbuf, theta, omega, q, ext, n, h,
 *             amps_on, wd_fault, offset, stop_mid, stop_lim, x) -> encoders, or None
 *
 * ReisPlant._integrate's rigid branch (compliance=False): the DAC registers -> motor torques (the
 * list comprehension's clamps; 0 and the brake's friction when the amplifiers are off), then
 * _steps_rigid's n semi-implicit Euler substeps of h [s] -- q = A theta, back-EMF, the joint
 * torques A^-T (tau_m - b w) - (C qd + g) + balancer (+ ext), M(q) + the rotors, qdd by numpy's
 * dgesv, the motor-side inertia (the einsum's sums in its order), Coulomb friction with stiction
 * -- and _write_outputs.  The same operations in the same order, every '@' through numpy's
 * dgemv.  The body: ``model`` (droid.sim.reis.dynamics.KernelRigidBody's buffer: rb_rnea and
 * rb_crba here, as its nle and mass call them) or, with model None, the callables nle(q, qd) and
 * mass(q) (Pinocchio's RigidBody), called with qbuf and qdbuf (float64 arrays of six) filled.
 * Writes the new state into x (24 float64: theta, omega, q, qd) and the registers and returns
 * the six encoder values written; or returns None having written nothing, for the Python
 * reference to take the advance: near a hard stop (|q - stop_mid| >= stop_lim, _near_stop's
 * test; _apply_stops), a state or torque not finite, a floating-point 'invalid', 'divide' or
 * 'overflow' (where numpy would warn), a singular M(q), a maximum/minimum of two opposite zeros.
 * (Jammed motors: the caller keeps those advances in Python.) */
static PyObject *rigid_steps(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 20) {
        PyErr_SetString(PyExc_TypeError, "rigid_steps takes 20 arguments");
        return NULL;
    }
    if (gemv_fn == NULL || gesv_fn == NULL) {
        PyErr_SetString(PyExc_RuntimeError, "droid._kernel: no BLAS dgemv or LAPACK dgesv set (droid.kernel sets them)");
        return NULL;
    }
    Bufs bs = {.n = 0};
    RbChain c;
    long enc[N];
    PyObject *mass_fn = args[4], *nle_fn = args[5];
    long n = PyLong_AsLong(args[12]);
    double h = PyFloat_AsDouble(args[13]);
    if (PyErr_Occurred())
        return NULL;
    unsigned char *regs = get(&bs, args[0], -MAP_MIN_SIZE, 1, "regs");
    const double *k = regs ? get(&bs, args[1], C_LEN * 8, 0, "consts") : NULL;
    const double *rc = k ? get(&bs, args[2], R_LEN * 8, 0, "rigid") : NULL;
    int ok = rc != NULL;
    double *qbuf = NULL, *qdbuf = NULL;
    c.m = NULL;
    if (ok && args[3] != Py_None) {
        ok = (c.m = get(&bs, args[3], (RB_PER_JOINT * N + 3) * 8, 0, "model")) != NULL;
        c.n = N;
    } else if (ok) {
        ok = PyCallable_Check(mass_fn) && PyCallable_Check(nle_fn);
        if (!ok)
            PyErr_SetString(PyExc_TypeError, "rigid_steps: without a model, mass and nle must be callables");
        ok = ok && (qbuf = get(&bs, args[6], N * 8, 1, "qbuf")) != NULL &&
             (qdbuf = get(&bs, args[7], N * 8, 1, "qdbuf")) != NULL;
    }
    const double *theta0 = ok ? get(&bs, args[8], N * 8, 0, "theta") : NULL;
    const double *omega0 = theta0 ? get(&bs, args[9], N * 8, 0, "omega") : NULL;
    const double *qnow = omega0 ? get(&bs, args[10], N * 8, 0, "q") : NULL;
    const double *ext = NULL;
    ok = qnow != NULL;
    if (ok && args[11] != Py_None)
        ok = (ext = get(&bs, args[11], N * 8, 0, "ext")) != NULL;
    int amps_on = ok ? PyObject_IsTrue(args[14]) : -1;
    int wd_fault = amps_on >= 0 ? PyObject_IsTrue(args[15]) : -1;
    const int64_t *offset = wd_fault >= 0 ? get(&bs, args[16], N * 8, 0, "offset") : NULL;
    const double *mid = offset ? get(&bs, args[17], N * 8, 0, "stop_mid") : NULL;
    const double *lim = mid ? get(&bs, args[18], N * 8, 0, "stop_lim") : NULL;
    double *x = lim ? get(&bs, args[19], 24 * 8, 1, "x") : NULL;
    if (x == NULL) {
        release(&bs);
        return NULL;
    }
    if (n < 1) {
        release(&bs);
        PyErr_SetString(PyExc_ValueError, "rigid_steps: n must be >= 1");
        return NULL;
    }
    const double *A = rc + R_A, *AinvT = rc + R_AINVT, *Ainv = rc + R_AINV, *jrot = rc + R_JROT;
    const double *b = rc + R_B, *w0 = rc + R_W0, *tmax = k + C_TAU_MAX, bal = k[C_BAL];
    double th[N], om[N], drive[N], tau_c[N];
    int amb = 0, finite = 1;
    for (int j = 0; j < N; j++) {  /* _near_stop: could a hard stop engage within the advance? */
        if (fabs(qnow[j] - mid[j]) >= lim[j]) {
            release(&bs);
            Py_RETURN_NONE;
        }
        th[j] = theta0[j];
        om[j] = omega0[j];
        finite &= isfinite(th[j]) && isfinite(om[j]) && (ext == NULL || isfinite(ext[j]));
        /* _integrate's drive: min(tm, max(-tm, float(min(hi, max(lo, d))) * k)) as Python's min/max */
        if (amps_on) {
            double d = rd_i16(regs + DAC_OFFSET + 2 * j), v, tm = tmax[j];
            d = d > DAC_MIN ? d : DAC_MIN;
            v = (d < DAC_MAX ? d : DAC_MAX) * k[C_TAU_PER_DAC + j];
            v = v > -tm ? v : -tm;
            drive[j] = v < tm ? v : tm;
            tau_c[j] = k[C_TAU_C + j];
        } else {
            drive[j] = 0.0;
            tau_c[j] = k[C_TAU_C + j] + k[C_TAU_BRAKE + j];
        }
    }
    if (!finite) {
        release(&bs);
        Py_RETURN_NONE;
    }
    fexcept_t saved;
    fegetexceptflag(&saved, FE_ALL_EXCEPT);
    feclearexcept(FP_BAD);
    int bad = 0;
    long info = 0;
    double q[N], qd[N], u[N], t[N], nl[N], tau[N], M[N * N], mt[N * N], qdd[N], y[N];
    for (long s = 0; s < n && !bad && !amb; s++) {
        matvec(A, N, N, th, q);  /* q = A @ theta, qd = A @ omega */
        matvec(A, N, N, om, qd);
        for (int j = 0; j < N; j++) {
            /* fade = tau_max * (omega / w0) if amps else 0.0;
               tau_m = np.minimum(np.maximum(drive, -tau_max - fade), tau_max - fade) */
            double fade = amps_on ? tmax[j] * (om[j] / w0[j]) : 0.0;
            double tm = np_minimum(np_maximum(drive[j], -tmax[j] - fade, &amb), tmax[j] - fade, &amb);
            u[j] = tm - b[j] * om[j];
        }
        matvec(AinvT, N, N, u, t);  /* AinvT @ (tau_m - b * omega) */
        if (c.m != NULL) {  /* KernelRigidBody.nle: rb_rnea with gravity, qdd None */
            rb_frames(&c, q);
            rb_rnea(&c, qd, NULL, 1, nl);
        } else {
            bad |= fetestexcept(FP_BAD) != 0;  /* numpy clears the flags in the callback's ufuncs */
            memcpy(qbuf, q, sizeof q);
            memcpy(qdbuf, qd, sizeof qd);
            if (copy_answer(PyObject_CallFunctionObjArgs(nle_fn, args[6], args[7], NULL), nl, N, "nle") < 0)
                goto error;
            feclearexcept(FP_BAD);
        }
        for (int j = 0; j < N; j++)
            tau[j] = t[j] - nl[j];
        tau[1] += -bal * sin(q[1]);  /* the balancer */
        if (ext != NULL)
            for (int j = 0; j < N; j++)
                tau[j] = tau[j] + ext[j];
        if (c.m != NULL) {  /* KernelRigidBody.mass: rb_crba */
            rb_crba(&c, M);
        } else {
            bad |= fetestexcept(FP_BAD) != 0;
            memcpy(qbuf, q, sizeof q);
            if (copy_answer(PyObject_CallFunctionObjArgs(mass_fn, args[6], NULL), M, N * N, "mass") < 0)
                goto error;
            feclearexcept(FP_BAD);
        }
        for (int i = 0; i < N * N; i++)
            mt[i] = M[i] + jrot[i];
        info = gesv(mt, N, tau, qdd);  /* _solve(m_tot, tau) */
        if (info != 0) {
            bad = 1;
            break;
        }
        matvec(Ainv, N, N, qdd, y);  /* w = omega + h * (Ainv @ qdd) */
        for (int i = 0; i < N; i++) {
            /* j_eff = np.einsum("ji,jk,ki->i", A, m_tot, A): numpy's loop, j outer, k inner,
               (A[j,i] * m[j,k]) * A[k,i] added to the output from 0 */
            double acc = 0.0;
            for (int j = 0; j < N; j++)
                for (int kk = 0; kk < N; kk++)
                    acc = (A[j * N + i] * mt[j * N + kk]) * A[kk * N + i] + acc;
            double w = om[i] + h * y[i];
            double fr = h * tau_c[i] / acc;  /* (h * tau_c) / j_eff */
            /* np.where(w > fr, w - fr, np.where(w < -fr, w + fr, 0.0)) */
            om[i] = w > fr ? w - fr : (w < -fr ? w + fr : 0.0);
        }
        for (int j = 0; j < N; j++)
            th[j] = th[j] + h * om[j];
    }
    if (!bad && !amb) {
        matvec(A, N, N, th, x + 12);  /* self._q = A @ theta, self._qd = A @ omega */
        matvec(A, N, N, om, x + 18);
        bad = fetestexcept(FP_BAD) != 0;
        for (int j = 0; j < N; j++) {
            x[j] = th[j];
            x[6 + j] = om[j];
        }
        for (int i = 0; i < 24; i++)
            bad |= !isfinite(x[i]);
    }
    fesetexceptflag(&saved, FE_ALL_EXCEPT);
    if (bad || amb) {
        release(&bs);
        Py_RETURN_NONE;
    }
    if (write_outputs(regs, k, x, x + 12, offset, amps_on, wd_fault, enc) < 0)
        goto error;
    release(&bs);
    return enc_tuple(enc);
error:
    fesetexceptflag(&saved, FE_ALL_EXCEPT);
    release(&bs);
    return NULL;
}


/* -- the seam tracker's nearest patch segment (droid.tasks.seam.patch.nearest_segment) ----------- */

/* a 3-term sum as numpy's c_einsum("ij,ij->i") adds one row's products: its SIMD loop's order,
 * ``order`` 0: (p0 + p2) + p1 (AVX-512's 8 lanes), 1: (p0 + p1) + p2 (AVX2's 4); then into the
 * zeroed output (+ 0.0).  droid.experiments.seam_kernel finds which one numpy uses, bit for bit. */
static inline double sum3(double p0, double p1, double p2, int order)
{
    double s = order == 0 ? (p0 + p2) + p1 : (p0 + p1) + p2;
    return s + 0.0;
}

/* seam_nearest(tool, a, ab, den, ok, order, foot) -> j: the patch segment nearest the tool point,
 * as nearest_segment computes it in numpy -- u = (tool - a) . ab / den, 0 where not ok, clipped to
 * [0, 1]; foot = a + u ab; j = argmin |foot - tool|^2 (the first; a NaN first) -- with foot[j] into
 * ``foot`` (3 doubles).  tool: 3 doubles; a, ab: m x 3; den: m doubles; ok: m bools (m >= 1). */
static PyObject *seam_nearest(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 7) {
        PyErr_SetString(PyExc_TypeError, "seam_nearest takes 7 arguments");
        return NULL;
    }
    int order = (int)PyLong_AsLong(args[5]);
    if (order == -1 && PyErr_Occurred())
        return NULL;
    Bufs bs = {.n = 0};
    const double *tool = get(&bs, args[0], 24, 0, "tool");
    const double *ab = tool ? get(&bs, args[2], -24, 0, "ab") : NULL;
    Py_ssize_t m = ab ? bs.b[1].len / 24 : 0;
    if (ab != NULL && bs.b[1].len != m * 24) {
        PyErr_SetString(PyExc_ValueError, "seam_nearest: ab is not m x 3 doubles");
        ab = NULL;
    }
    const double *a = ab ? get(&bs, args[1], m * 24, 0, "a") : NULL;
    const double *den = a ? get(&bs, args[3], m * 8, 0, "den") : NULL;
    const unsigned char *ok = den ? get(&bs, args[4], m, 0, "ok") : NULL;
    double *foot = ok ? get(&bs, args[6], 24, 1, "foot") : NULL;
    if (foot == NULL) {
        release(&bs);
        return NULL;
    }
    const double t0 = tool[0], t1 = tool[1], t2 = tool[2];
    Py_ssize_t best = 0;
    double bd = 0.0;
    for (Py_ssize_t i = 0; i < m; i++) {
        const double *ai = a + 3 * i, *bi = ab + 3 * i;
        double u = sum3((t0 - ai[0]) * bi[0], (t1 - ai[1]) * bi[1], (t2 - ai[2]) * bi[2], order) / den[i];
        if (!ok[i])
            u = 0.0;
        u = u < 0.0 ? 0.0 : (u > 1.0 ? 1.0 : u); /* np.clip (NaN stays) */
        double f0 = ai[0] + u * bi[0], f1 = ai[1] + u * bi[1], f2 = ai[2] + u * bi[2];
        double o0 = f0 - t0, o1 = f1 - t1, o2 = f2 - t2;
        double d = sum3(o0 * o0, o1 * o1, o2 * o2, order);
        if (i == 0 || d < bd || d != d) {
            best = i;
            bd = d;
            foot[0] = f0, foot[1] = f1, foot[2] = f2;
            if (d != d)
                break; /* np.argmin: the first NaN */
        }
    }
    release(&bs);
    return PyLong_FromSsize_t(best);
}


/* == the tracker's pose interpolation (droid.tasks.seam.cycle.interpolate_pose; issue 44, h50) ==
 *
 * interpolate_pose(T0, T1, u) in numpy: out[:3, 3] = t0 + u (t1 - t0); out[:3, :3] = R0 exp(u log(R0^T
 * R1)) (rotation log/exp of droid.tasks.seam.cycle._rot_log/_rot_exp).  Every elementwise operation
 * is IEEE's and written here in the reference's order; what numpy leaves to its BLAS and its reduce
 * loop is chosen by ``order`` (a packed int, droid.experiments.seam_kernel finds the one numpy uses
 * on this machine, bit for bit, and keeps the reference where none matches):
 *   bits 0-3: the 3x3 product R0^T R1 (numpy's dgemm, A transposed), bits 4-7: the products K K and
 *   R0 E (dgemm, neither transposed): how one entry's three products are summed (pose_sum3);
 *   bits 8-11: v . v (cblas_ddot) the same way; bit 12: the trace, (r00 + r11) + r22 (0) or
 *   r00 + (r11 + r22) (1: numpy's reduce adds the rest to the first). */

/* a0 b0 + a1 b1 + a2 b2 in one of the orders a BLAS kernel may take; form 8 set: + 0.0 at the end
 * (a kernel that adds into a zeroed output) */
static inline double pose_sum3(double a0, double b0, double a1, double b1, double a2, double b2, int form)
{
    double s;
    switch (form & 7) {
    case 0: s = (a0 * b0 + a1 * b1) + a2 * b2; break;
    case 1: s = (a0 * b0 + a2 * b2) + a1 * b1; break;
    case 2: s = fma(a2, b2, fma(a1, b1, a0 * b0)); break;
    case 3: s = fma(a0, b0, fma(a1, b1, a2 * b2)); break;
    case 4: s = fma(a2, b2, a0 * b0) + a1 * b1; break;
    default: s = fma(a1, b1, a0 * b0) + a2 * b2; break;
    }
    return (form & 8) ? s + 0.0 : s;
}

/* c = a b (3x3; a's rows ``lda`` doubles apart, transposed if ``ta``; b's ``ldb``; c dense) */
static void pose_mul3(const double *a, int lda, int ta, const double *b, int ldb, double *c, int form)
{
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            double a0 = ta ? a[i] : a[lda * i], a1 = ta ? a[lda + i] : a[lda * i + 1],
                   a2 = ta ? a[2 * lda + i] : a[lda * i + 2];
            c[3 * i + j] = pose_sum3(a0, b[j], a1, b[ldb + j], a2, b[2 * ldb + j], form);
        }
}

/* the pose a fraction u of the way from T0 to T1 (4x4 row-major, mm) into out */
static void pose_interp_c(const double *T0, const double *T1, double u, int order, double *out)
{
    const int f_tn = order & 15, f_nn = (order >> 4) & 15, f_dot = (order >> 8) & 15, f_tr = (order >> 12) & 1;
    double M[9], E[9], KK[9], K[9];
    pose_mul3(T0, 4, 1, T1, 4, M, f_tn);  /* T0[:3, :3].T @ T1[:3, :3] */
    /* _rot_log(M) */
    double tr = f_tr ? M[0] + (M[4] + M[8]) : (M[0] + M[4]) + M[8];
    double x = (tr - 1.0) / 2.0;
    double m = x < 1.0 ? x : 1.0;  /* min(1.0, x): 1.0 unless x < 1.0 (NaN: 1.0) */
    double c = m > -1.0 ? m : -1.0;  /* max(-1.0, m) */
    double a = acos(c);
    double w0 = M[7] - M[5], w1 = M[2] - M[6], w2 = M[3] - M[1];
    if (a < 1e-9) {
        w0 = w0 / 2.0, w1 = w1 / 2.0, w2 = w2 / 2.0;
    } else {
        double k = a / (2.0 * sin(a));
        w0 = w0 * k, w1 = w1 * k, w2 = w2 * k;
    }
    /* u * w, then _rot_exp */
    double v0 = u * w0, v1 = u * w1, v2 = u * w2;
    double n = sqrt(pose_sum3(v0, v0, v1, v1, v2, v2, f_dot));
    if (n < 1e-12) {
        for (int i = 0; i < 9; i++)
            E[i] = (i % 4 == 0) ? 1.0 : 0.0;
    } else {
        double k0 = v0 / n, k1 = v1 / n, k2 = v2 / n;
        K[0] = 0.0, K[1] = -k2, K[2] = k1;
        K[3] = k2, K[4] = 0.0, K[5] = -k0;
        K[6] = -k1, K[7] = k0, K[8] = 0.0;
        pose_mul3(K, 3, 0, K, 3, KK, f_nn);
        double s = sin(n), c1 = 1.0 - cos(n);
        for (int i = 0; i < 9; i++)
            E[i] = (((i % 4 == 0) ? 1.0 : 0.0) + s * K[i]) + c1 * KK[i];
    }
    double R[9];
    pose_mul3(T0, 4, 0, E, 3, R, f_nn);  /* T0[:3, :3] @ exp(...) */
    for (int i = 0; i < 3; i++) {
        out[4 * i] = R[3 * i], out[4 * i + 1] = R[3 * i + 1], out[4 * i + 2] = R[3 * i + 2];
        out[4 * i + 3] = T0[4 * i + 3] + u * (T1[4 * i + 3] - T0[4 * i + 3]);
    }
    out[12] = 0.0, out[13] = 0.0, out[14] = 0.0, out[15] = 1.0;
}

/* pose_interp(T0, T1, u, order, out): interpolate_pose's pose into out (4x4 float64 each) */
static PyObject *pose_interp(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 5) {
        PyErr_SetString(PyExc_TypeError, "pose_interp takes 5 arguments");
        return NULL;
    }
    double u = PyFloat_AsDouble(args[2]);
    if (u == -1.0 && PyErr_Occurred())
        return NULL;
    int order = (int)PyLong_AsLong(args[3]);
    if (order == -1 && PyErr_Occurred())
        return NULL;
    Bufs bs = {.n = 0};
    const double *T0 = get(&bs, args[0], 128, 0, "T0");
    const double *T1 = T0 ? get(&bs, args[1], 128, 0, "T1") : NULL;
    double *out = T1 ? get(&bs, args[4], 128, 1, "out") : NULL;
    if (out == NULL) {
        release(&bs);
        return NULL;
    }
    pose_interp_c(T0, T1, u, order, out);
    release(&bs);
    Py_RETURN_NONE;
}

/* pose_probe(kind, a, b, form, out): one part of pose_interp alone, for finding numpy's orders --
 * kind 0: out (3x3) = a[:3, :3].T @ b[:3, :3] (a, b 4x4); 1: out = a[:3, :3] @ b (b 3x3); 2: out = a @ b
 * (3x3 each); 3: out[0] = a[:3] . a[:3] (a 3 doubles); 4: out[0] = trace(a) (3x3), form 0 or 1 */
static PyObject *pose_probe(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 5) {
        PyErr_SetString(PyExc_TypeError, "pose_probe takes 5 arguments");
        return NULL;
    }
    int kind = (int)PyLong_AsLong(args[0]);
    int form = kind == -1 && PyErr_Occurred() ? 0 : (int)PyLong_AsLong(args[3]);
    if (PyErr_Occurred())
        return NULL;
    static const Py_ssize_t la[] = {128, 128, 72, 24, 72}, lb[] = {128, 72, 72, -8, -8};
    if (kind < 0 || kind > 4) {
        PyErr_SetString(PyExc_ValueError, "pose_probe: kind is 0..4");
        return NULL;
    }
    Bufs bs = {.n = 0};
    const double *a = get(&bs, args[1], la[kind], 0, "a");
    const double *b = a ? get(&bs, args[2], lb[kind], 0, "b") : NULL;
    double *out = b ? get(&bs, args[4], kind < 3 ? 72 : 8, 1, "out") : NULL;
    if (out == NULL) {
        release(&bs);
        return NULL;
    }
    if (kind == 0)
        pose_mul3(a, 4, 1, b, 4, out, form);
    else if (kind == 1)
        pose_mul3(a, 4, 0, b, 3, out, form);
    else if (kind == 2)
        pose_mul3(a, 3, 0, b, 3, out, form);
    else if (kind == 3)
        out[0] = pose_sum3(a[0], a[0], a[1], a[1], a[2], a[2], form);
    else
        out[0] = form ? a[0] + (a[4] + a[8]) : (a[0] + a[4]) + a[8];
    release(&bs);
    Py_RETURN_NONE;
}
/* == end of the pose interpolation block (h50) == */


static PyMethodDef methods[] = {
    {"set_gemv", set_gemv, METH_VARARGS, "set_gemv(address, int64): the cblas_dgemv to call (numpy's)"},
    {"exact_step", (PyCFunction)(void (*)(void))exact_step, METH_FASTCALL,
     "exact_step(regs, consts, pg, g_m, theta, omega, q, qd, tau_link, ext, amps_on, wd_fault, offset, x) "
     "-> encoders: the plant's exact zero-order-hold step (droid.sim.reis.plant); with 18 arguments (regs, consts, "
     "pg, g_m, theta, omega, q, qd, nle, ext, amps_on, wd_fault, offset, x, lin_q, relin_rad, stop_mid, stop_lim) "
     "exact_checks' guards first (1 or 2 returned, nothing changed), then nle(q, qd) and the step"},
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
    {"servo_cycle", (PyCFunction)(void (*)(void))servo_cycle, METH_FASTCALL,
     "servo_cycle(regs, pos, queue, qi, target, vel, lo, hi, fe_max, gains, state, first, span, max_step) "
     "-> (raw, dacs) or None: ServoStation.cycle's common tick"},
    {"servo_status", (PyCFunction)(void (*)(void))servo_status, METH_FASTCALL,
     "servo_status(tick, mode, homing_joint, starved, braking, fault, amps_on, pos, target, zero, dac) -> bytes "
     "or None: ServoCore.status_message"},
    {"write_dacs", (PyCFunction)(void (*)(void))write_dacs, METH_FASTCALL,
     "write_dacs(regs, values) -> written or None: VmeBus.write_dacs for six ints"},
    {"rb_rnea", (PyCFunction)(void (*)(void))py_rb_rnea, METH_FASTCALL,
     "rb_rnea(model, q, qd, qdd, gravity, tau): tau = M(q) qdd + C(q, qd) qd + g(q) [N m] (None: zero)"},
    {"rb_crba", (PyCFunction)(void (*)(void))py_rb_crba, METH_FASTCALL, "rb_crba(model, q, M): M(q) [kg m^2]"},
    {"rb_minv", (PyCFunction)(void (*)(void))py_rb_minv, METH_FASTCALL, "rb_minv(model, q, Minv): M(q)^-1"},
    {"rb_aba", (PyCFunction)(void (*)(void))py_rb_aba, METH_FASTCALL,
     "rb_aba(model, q, qd, tau, qdd): qdd = M(q)^-1 (tau - C(q, qd) qd - g(q)) [rad/s^2]"},
    {"set_gesv", set_gesv, METH_VARARGS, "set_gesv(address, int64): the LAPACK dgesv to call (numpy's)"},
    {"solve", (PyCFunction)(void (*)(void))py_solve, METH_FASTCALL, "solve(a, b, x) -> info: x = a^-1 b by the dgesv set"},
    {"rigid_steps", (PyCFunction)(void (*)(void))rigid_steps, METH_FASTCALL,
     "rigid_steps(regs, consts, rigid, model, mass, nle, qbuf, qdbuf, theta, omega, q, ext, n, h, amps_on, "
     "wd_fault, offset, stop_mid, stop_lim, x) -> encoders or None: the plant's rigid-drive substeps"},
    {"rb_jacobian", (PyCFunction)(void (*)(void))py_rb_jacobian, METH_FASTCALL,
     "rb_jacobian(model, q, J, oM): the last joint's placement (4x4 [m]) and 6 x n LOCAL_WORLD_ALIGNED Jacobian"},
    {"seam_nearest", (PyCFunction)(void (*)(void))seam_nearest, METH_FASTCALL,
     "seam_nearest(tool, a, ab, den, ok, order, foot) -> j: droid.tasks.seam.patch.nearest_segment"},
    {"pose_interp", (PyCFunction)(void (*)(void))pose_interp, METH_FASTCALL,
     "pose_interp(T0, T1, u, order, out): droid.tasks.seam.cycle.interpolate_pose into out (h50)"},
    {"pose_probe", (PyCFunction)(void (*)(void))pose_probe, METH_FASTCALL,
     "pose_probe(kind, a, b, form, out): one part of pose_interp, for finding numpy's orders (h50)"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "droid._kernel",
                                    "The compiled 500 Hz pair: the plant's exact step and the servo's PID; the plant's rigid-drive substeps; a serial arm's rigid-body dynamics.", -1,
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
        PyModule_AddIntConstant(m, "C_LEN", C_LEN) < 0 ||
        PyModule_AddIntConstant(m, "RB_PER_JOINT", RB_PER_JOINT) < 0 ||
        PyModule_AddIntConstant(m, "RB_MAXJ", RB_MAXJ) < 0 ||
        PyModule_AddIntConstant(m, "R_LEN", R_LEN) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
