/* droid._guard -- the collision guard's distance pass, compiled (issue 41 item 5; docs/guard.md).
 *
 * One pass over every checked pair of a cell's bodies for B joint configurations of its arms:
 * the same forward kinematics and the same capsule/box distances as the Python reference
 * (droid.guard.bodies.ArmChain.points, droid.guard.cell.GuardScene.distances_reference,
 * droid.guard.distance), operation for operation, in doubles.  The reference stays the
 * specification; tests/guard/test_guard_kernel.py compares the two on random configurations
 * (agreement to 1e-9 mm: numpy's einsum and matmul may add in another order).
 *
 * A Scene is built once from the reference's arrays (droid.guard.kernel.compiled_scene):
 *
 *   Scene(n_arms, arm_data, caps_i, caps_r, boxes_i, boxes_d, pairs)
 *     arm_data  float64[n_arms * ARM_DOUBLES]: base 4x4, K 6x3x3, KK 6x3x3, offsets 6x3,
 *               flange 3, tip_R 3x3, tool_T 4x4, has_tool (1.0 / 0.0)
 *     caps_i    int32[n_caps * 3]: arm, end 0, end 1 (indices into the arm's 8 points)
 *     caps_r    float64[n_caps]: radii [mm]
 *     boxes_i   int32[n_boxes]: arm, or -1 for a fixture
 *     boxes_d   float64[n_boxes * 19]: T 4x4 (on tool0 for an arm's box, global for a fixture),
 *               half sizes 3 [mm]
 *     pairs     int32[(n_cc + n_cb + n_bb) * 2 + 3]: n_cc, n_cb, n_bb, then the index pairs
 *               (caps, caps), (caps, boxes), (boxes, boxes), in the reference's order
 *
 *   scene.distances(q, out)   q: float64[B * n_arms * 6] joint vectors [deg], arm by arm;
 *                             out: float64[B * n_pairs] (writable) the pairs' distances [mm]
 *   scene.closest(q, out, pa, pb)   the same distances and each pair's closest points [mm,
 *                             global]: pa, pb float64[B * n_pairs * 3] (writable), as
 *                             droid.guard.cell.GuardScene.closest_points_reference gives them
 *                             (a capsule's on its axis; ties broken alike: the first least
 *                             candidate; an axis or edge entering a box: its entry point twice)
 *   scene.poses(q, p0, p1, bc, bR)   the bodies' poses [mm, global] as GuardScene._poses gives
 *                             them: capsule ends float64[B * n_caps * 3] x2, box centres
 *                             float64[B * n_boxes * 3] and rotations float64[B * n_boxes * 9]
 *
 * Built by setup.py (a second Extension beside droid._kernel) with the same flags: -O2, no
 * fast-math, no FMA contraction.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#define ARM_DOUBLES (16 + 54 + 54 + 18 + 3 + 9 + 16 + 1)
#define BOX_DOUBLES 19
static const double EPS = 1e-12;
static const double DEG2RAD = 0.017453292519943295; /* numpy.radians: x * (pi / 180) */

typedef struct {
    PyObject_HEAD
    int n_arms, n_caps, n_boxes, n_cc, n_cb, n_bb;
    double *arm;    /* n_arms * ARM_DOUBLES */
    int *caps_i;    /* n_caps * 3 */
    double *caps_r; /* n_caps */
    int *boxes_i;   /* n_boxes */
    double *boxes_d; /* n_boxes * BOX_DOUBLES */
    int *pairs;     /* (n_cc + n_cb + n_bb) * 2 */
    double *pts;    /* scratch: n_arms * 8 * 3 (joint origins, flange, tool point) */
    double *tool0;  /* scratch: n_arms * 16 */
    double *bc;     /* scratch: n_boxes * 3 centres */
    double *bR;     /* scratch: n_boxes * 9 rotations */
} Scene;

static inline double dot3(const double *a, const double *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
static inline double clip01(double v) { return v < 0.0 ? 0.0 : (v > 1.0 ? 1.0 : v); }

/* droid.guard.distance.segment_segment_points, one pair: the distance; the closest points into
 * c1, c2 where they are not NULL */
static double segment_segment(const double *p1, const double *q1, const double *p2, const double *q2,
                              double *c1, double *c2) {
    double d1[3], d2[3], r[3], diff[3], a1[3], a2[3];
    for (int k = 0; k < 3; k++) { d1[k] = q1[k] - p1[k]; d2[k] = q2[k] - p2[k]; r[k] = p1[k] - p2[k]; }
    double a = dot3(d1, d1), e = dot3(d2, d2), f = dot3(d2, r);
    double c = dot3(d1, r), b = dot3(d1, d2);
    int a_ok = a > EPS, e_ok = e > EPS;
    double a_safe = a_ok ? a : 1.0, e_safe = e_ok ? e : 1.0;
    double denom = a * e - b * b;
    double ae = a * e;
    double s = denom > EPS * (ae > 1.0 ? ae : 1.0) ? clip01((b * f - c * e) / (denom > 0 ? denom : 1.0)) : 0.0;
    double t = (b * s + f) / e_safe;
    s = t < 0.0 ? clip01(-c / a_safe) : (t > 1.0 ? clip01((b - c) / a_safe) : s);
    t = clip01(t);
    if (!a_ok) { s = 0.0; t = clip01(f / e_safe); }
    if (!e_ok) { s = a_ok ? clip01(-c / a_safe) : 0.0; t = 0.0; }
    for (int k = 0; k < 3; k++) { a1[k] = p1[k] + d1[k] * s; a2[k] = p2[k] + d2[k] * t; diff[k] = a1[k] - a2[k]; }
    if (c1 != NULL) memcpy(c1, a1, sizeof a1);
    if (c2 != NULL) memcpy(c2, a2, sizeof a2);
    return sqrt(dot3(diff, diff));
}

static double point_box(const double *p, const double *h) {
    double g[3];
    for (int k = 0; k < 3; k++) { double v = fabs(p[k]) - h[k]; g[k] = v > 0.0 ? v : 0.0; }
    return sqrt(dot3(g, g));
}

static int segment_enters_box(const double *p, const double *q, const double *h) {
    double lo = -INFINITY, hi = INFINITY;
    for (int k = 0; k < 3; k++) {
        double d = q[k] - p[k];
        if (fabs(d) < EPS) {
            if (!(fabs(p[k]) <= h[k])) return 0;
            continue;
        }
        double t0 = (-h[k] - p[k]) / d, t1 = (h[k] - p[k]) / d;
        double l = t0 < t1 ? t0 : t1, u = t0 > t1 ? t0 : t1;
        if (l > lo) lo = l;
        if (u < hi) hi = u;
    }
    double tmin = lo > 0.0 ? lo : 0.0, tmax = hi < 1.0 ? hi : 1.0;
    return tmin <= tmax;
}

/* the 12 edges of [-1, 1]^3, as droid.guard.distance.UNIT_BOX_EDGES orders them */
static double UNIT_EDGES[12][2][3];

static void init_edges(void) {
    double corners[8][3];
    int n = 0;
    for (int x = 0; x < 2; x++)
        for (int y = 0; y < 2; y++)
            for (int z = 0; z < 2; z++) {
                corners[n][0] = x ? 1.0 : -1.0; corners[n][1] = y ? 1.0 : -1.0; corners[n][2] = z ? 1.0 : -1.0;
                n++;
            }
    int m = 0;
    for (int a = 0; a < 8; a++)
        for (int b = a + 1; b < 8; b++) {
            int diff = 0;
            for (int k = 0; k < 3; k++) diff += corners[a][k] != corners[b][k];
            if (diff == 1) {
                memcpy(UNIT_EDGES[m][0], corners[a], sizeof corners[a]);
                memcpy(UNIT_EDGES[m][1], corners[b], sizeof corners[b]);
                m++;
            }
        }
}

/* droid.guard.distance.segment_entry: the entry parameter of a segment that enters the box */
static double segment_entry(const double *p, const double *q, const double *h) {
    double lo = -INFINITY;
    for (int k = 0; k < 3; k++) {
        double d = q[k] - p[k];
        if (fabs(d) < EPS) continue;
        double t0 = (-h[k] - p[k]) / d, t1 = (h[k] - p[k]) / d;
        double l = t0 < t1 ? t0 : t1;
        if (l > lo) lo = l;
    }
    double t = lo > 0.0 ? lo : 0.0;
    return t < 1.0 ? t : 1.0;
}

static inline void clamp_box(const double *p, const double *h, double *out) {
    for (int k = 0; k < 3; k++) { double v = p[k] > -h[k] ? p[k] : -h[k]; out[k] = v < h[k] ? v : h[k]; }
}

/* droid.guard.distance.segment_box (segment_box_points where cs, cb are not NULL: the closest
 * points, in the box's frame; the candidates p, q, then the 12 edges, the first least one wins):
 * p, q in the box's frame.  An edge whose bounding sphere is farther from the segment's than the
 * best so far cannot give the least distance, and is not measured: the least of the rest is the
 * same value, and the same candidate (the pruning changes no result). */
static double segment_box(const double *p, const double *q, const double *h, double *cs, double *cb) {
    if (segment_enters_box(p, q, h)) {
        if (cs != NULL) {
            double t = segment_entry(p, q, h);
            for (int k = 0; k < 3; k++) { cs[k] = p[k] + t * (q[k] - p[k]); cb[k] = cs[k]; }
        }
        return 0.0;
    }
    double dp = point_box(p, h), dq = point_box(q, h);
    double d = dp;
    const double *end = p;
    if (dq < d) { d = dq; end = q; }
    if (cs != NULL) { memcpy(cs, end, 3 * sizeof(double)); clamp_box(end, h, cb); }
    double de = INFINITY;
    double mid[3] = {0.5 * (p[0] + q[0]), 0.5 * (p[1] + q[1]), 0.5 * (p[2] + q[2])};
    double hs[3] = {0.5 * (q[0] - p[0]), 0.5 * (q[1] - p[1]), 0.5 * (q[2] - p[2])};
    double rs = sqrt(dot3(hs, hs)) * (1.0 + 1e-12) + 1e-9;
    for (int m = 0; m < 12; m++) {
        double e0[3], e1[3], c[3];
        double best = d < de ? d : de;
        int axis = 0;
        for (int k = 0; k < 3; k++) {
            e0[k] = UNIT_EDGES[m][0][k] * h[k];
            e1[k] = UNIT_EDGES[m][1][k] * h[k];
            if (UNIT_EDGES[m][0][k] != UNIT_EDGES[m][1][k]) axis = k;
            c[k] = 0.5 * (e0[k] + e1[k]) - mid[k];
        }
        double gap = sqrt(dot3(c, c)) - rs - h[axis] * (1.0 + 1e-12) - 1e-9;
        if (gap > best) continue;
        if (cs == NULL) {
            double v = segment_segment(p, q, e0, e1, NULL, NULL);
            if (v < de) de = v;
        } else {
            double s1[3], s2[3];
            double v = segment_segment(p, q, e0, e1, s1, s2);
            if (v < best) { de = v; memcpy(cs, s1, sizeof s1); memcpy(cb, s2, sizeof s2); }
        }
    }
    return d < de ? d : de;
}

/* points (global) into a box's frame: R^T (x - c) */
static inline void to_frame(const double *x, const double *c, const double *R, double *out) {
    double rel[3] = {x[0] - c[0], x[1] - c[1], x[2] - c[2]};
    for (int i = 0; i < 3; i++) out[i] = R[0 * 3 + i] * rel[0] + R[1 * 3 + i] * rel[1] + R[2 * 3 + i] * rel[2];
}

/* a box-frame point back to the global frame: c + R x */
static inline void from_frame(const double *x, const double *c, const double *R, double *out) {
    for (int i = 0; i < 3; i++) out[i] = c[i] + (R[i * 3 + 0] * x[0] + R[i * 3 + 1] * x[1] + R[i * 3 + 2] * x[2]);
}

/* 3x3 (row-major) products */
static inline void mat3_mul(const double *A, const double *B, double *C) {
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) C[i * 3 + j] = A[i * 3 + 0] * B[0 * 3 + j] + A[i * 3 + 1] * B[1 * 3 + j] + A[i * 3 + 2] * B[2 * 3 + j];
}
static inline void mat3_vec(const double *A, const double *v, double *out) {
    for (int i = 0; i < 3; i++) out[i] = A[i * 3 + 0] * v[0] + A[i * 3 + 1] * v[1] + A[i * 3 + 2] * v[2];
}
static inline void mat4_mul(const double *A, const double *B, double *C) {
    for (int i = 0; i < 4; i++)
        for (int j = 0; j < 4; j++)
            C[i * 4 + j] = A[i * 4 + 0] * B[0 * 4 + j] + A[i * 4 + 1] * B[1 * 4 + j] + A[i * 4 + 2] * B[2 * 4 + j]
                           + A[i * 4 + 3] * B[3 * 4 + j];
}

/* droid.guard.bodies.ArmChain.points for one arm and one joint vector [deg]; + the tool point */
static void arm_points(const double *a, const double *q_deg, double *pts, double *tool0) {
    const double *base = a, *K = a + 16, *KK = a + 70, *off = a + 124, *flange = a + 142, *tipR = a + 145;
    const double *toolT = a + 154;
    int has_tool = a[170] != 0.0;
    double R[9], o[3], Rn[9], rot[9], v[3];
    for (int i = 0; i < 3; i++) { for (int j = 0; j < 3; j++) R[i * 3 + j] = base[i * 4 + j]; o[i] = base[i * 4 + 3]; }
    for (int i = 0; i < 6; i++) {
        double qr = q_deg[i] * DEG2RAD, s = sin(qr), c = 1.0 - cos(qr);
        for (int m = 0; m < 9; m++) rot[m] = ((m % 4 == 0) ? 1.0 : 0.0) + s * K[i * 9 + m] + c * KK[i * 9 + m];
        mat3_vec(R, off + i * 3, v);
        for (int k = 0; k < 3; k++) { o[k] = o[k] + v[k]; pts[i * 3 + k] = o[k]; }
        mat3_mul(R, rot, Rn);
        memcpy(R, Rn, sizeof R);
    }
    mat3_vec(R, flange, v);
    for (int k = 0; k < 3; k++) pts[6 * 3 + k] = o[k] + v[k];
    mat3_mul(R, tipR, Rn);
    memset(tool0, 0, 16 * sizeof(double));
    for (int i = 0; i < 3; i++) { for (int j = 0; j < 3; j++) tool0[i * 4 + j] = Rn[i * 3 + j]; tool0[i * 4 + 3] = pts[6 * 3 + i]; }
    tool0[15] = 1.0;
    for (int i = 0; i < 3; i++)
        pts[7 * 3 + i] = has_tool ? tool0[i * 4 + 0] * toolT[3] + tool0[i * 4 + 1] * toolT[7] + tool0[i * 4 + 2] * toolT[11]
                                        + tool0[i * 4 + 3] * toolT[15]
                                  : pts[6 * 3 + i];
}

/* one configuration's forward kinematics: every arm's points and tool0, every box's frame */
static void scene_fk(Scene *S, const double *q) {
    for (int n = 0; n < S->n_arms; n++) arm_points(S->arm + n * ARM_DOUBLES, q + n * 6, S->pts + n * 24, S->tool0 + n * 16);
    for (int k = 0; k < S->n_boxes; k++) {
        const double *T = S->boxes_d + k * BOX_DOUBLES;
        double W[16];
        const double *G = T;
        if (S->boxes_i[k] >= 0) { mat4_mul(S->tool0 + S->boxes_i[k] * 16, T, W); G = W; }
        for (int i = 0; i < 3; i++) { S->bc[k * 3 + i] = G[i * 4 + 3]; for (int j = 0; j < 3; j++) S->bR[k * 9 + i * 3 + j] = G[i * 4 + j]; }
    }
}

/* one configuration: every pair's distance into out, and (pa, pb not NULL) its closest points */
static void scene_pass(Scene *S, const double *q, double *out, double *pa, double *pb) {
    scene_fk(S, q);
    int want = pa != NULL;
    const int *pr = S->pairs;
    int o = 0;
    for (int p = 0; p < S->n_cc; p++, pr += 2, o++) {
        const int *ci = S->caps_i + pr[0] * 3, *cj = S->caps_i + pr[1] * 3;
        const double *Pi = S->pts + ci[0] * 24, *Pj = S->pts + cj[0] * 24;
        double d = segment_segment(Pi + ci[1] * 3, Pi + ci[2] * 3, Pj + cj[1] * 3, Pj + cj[2] * 3,
                                   want ? pa + o * 3 : NULL, want ? pb + o * 3 : NULL);
        out[o] = d - S->caps_r[pr[0]] - S->caps_r[pr[1]];
    }
    for (int p = 0; p < S->n_cb; p++, pr += 2, o++) {
        const int *ci = S->caps_i + pr[0] * 3;
        const double *Pi = S->pts + ci[0] * 24, *h = S->boxes_d + pr[1] * BOX_DOUBLES + 16;
        const double *c = S->bc + pr[1] * 3, *R = S->bR + pr[1] * 9;
        double a[3], b[3], cs[3], cb[3];
        to_frame(Pi + ci[1] * 3, c, R, a);
        to_frame(Pi + ci[2] * 3, c, R, b);
        double d = segment_box(a, b, h, want ? cs : NULL, want ? cb : NULL), r = S->caps_r[pr[0]];
        out[o] = d > 0.0 ? d - r : -r;
        if (want) { from_frame(cs, c, R, pa + o * 3); from_frame(cb, c, R, pb + o * 3); }
    }
    for (int p = 0; p < S->n_bb; p++, pr += 2, o++) {
        double best[2] = {INFINITY, INFINITY}, bs[2][3] = {{0}}, bb[2][3] = {{0}};
        for (int dir = 0; dir < 2; dir++) {
            int k1 = dir ? pr[1] : pr[0], k2 = dir ? pr[0] : pr[1];
            const double *h1 = S->boxes_d + k1 * BOX_DOUBLES + 16, *h2 = S->boxes_d + k2 * BOX_DOUBLES + 16;
            const double *c1 = S->bc + k1 * 3, *R1 = S->bR + k1 * 9, *c2 = S->bc + k2 * 3, *R2 = S->bR + k2 * 9;
            for (int m = 0; m < 12; m++) {
                double w[2][3], e[2][3], cs[3], cb[3];
                for (int end = 0; end < 2; end++) {
                    double loc[3] = {UNIT_EDGES[m][end][0] * h1[0], UNIT_EDGES[m][end][1] * h1[1], UNIT_EDGES[m][end][2] * h1[2]};
                    double v[3];
                    mat3_vec(R1, loc, v);
                    for (int k = 0; k < 3; k++) w[end][k] = c1[k] + v[k];
                    to_frame(w[end], c2, R2, e[end]);
                }
                double d = segment_box(e[0], e[1], h2, want ? cs : NULL, want ? cb : NULL);
                if (d < best[dir]) {
                    best[dir] = d;
                    if (want) { from_frame(cs, c2, R2, bs[dir]); from_frame(cb, c2, R2, bb[dir]); }
                }
            }
        }
        int first = best[0] <= best[1];
        out[o] = first ? best[0] : best[1];
        if (want) {  /* dir 0: a's edge against box b; dir 1: b's edge against box a */
            memcpy(pa + o * 3, first ? bs[0] : bb[1], 3 * sizeof(double));
            memcpy(pb + o * 3, first ? bb[0] : bs[1], 3 * sizeof(double));
        }
    }
}

/* -- the Python type ---------------------------------------------------------------------------- */

static int copy_buffer(PyObject *obj, const char *fmt, Py_ssize_t itemsize, Py_ssize_t want, void **dst, const char *what) {
    Py_buffer view;
    if (PyObject_GetBuffer(obj, &view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0) return -1;
    int ok = view.itemsize == itemsize && (want < 0 || view.len == want * itemsize) && view.format
             && strchr(fmt, view.format[strlen(view.format) - 1]) != NULL;
    if (!ok) {
        PyBuffer_Release(&view);
        PyErr_Format(PyExc_ValueError, "_guard.Scene: %s: wrong type or size", what);
        return -1;
    }
    *dst = malloc(view.len > 0 ? (size_t)view.len : 1);
    if (*dst == NULL) { PyBuffer_Release(&view); PyErr_NoMemory(); return -1; }
    memcpy(*dst, view.buf, (size_t)view.len);
    PyBuffer_Release(&view);
    return 0;
}

static void Scene_dealloc(Scene *S) {
    free(S->arm); free(S->caps_i); free(S->caps_r); free(S->boxes_i); free(S->boxes_d); free(S->pairs);
    free(S->pts); free(S->tool0); free(S->bc); free(S->bR);
    Py_TYPE(S)->tp_free((PyObject *)S);
}

static int Scene_init(Scene *S, PyObject *args, PyObject *kw) {
    int n_arms;
    PyObject *arm, *caps_i, *caps_r, *boxes_i, *boxes_d, *pairs;
    if (!PyArg_ParseTuple(args, "iOOOOOO", &n_arms, &arm, &caps_i, &caps_r, &boxes_i, &boxes_d, &pairs)) return -1;
    Py_buffer cr, bi, pv;
    if (n_arms < 1) { PyErr_SetString(PyExc_ValueError, "_guard.Scene: no arm"); return -1; }
    if (PyObject_GetBuffer(caps_r, &cr, PyBUF_C_CONTIGUOUS) < 0) return -1;
    S->n_caps = (int)(cr.len / 8);
    PyBuffer_Release(&cr);
    if (PyObject_GetBuffer(boxes_i, &bi, PyBUF_C_CONTIGUOUS) < 0) return -1;
    S->n_boxes = (int)(bi.len / 4);
    PyBuffer_Release(&bi);
    if (PyObject_GetBuffer(pairs, &pv, PyBUF_C_CONTIGUOUS) < 0) return -1;
    Py_ssize_t n_pairs_items = pv.len / 4;
    if (n_pairs_items < 3) { PyBuffer_Release(&pv); PyErr_SetString(PyExc_ValueError, "_guard.Scene: pairs"); return -1; }
    const int *head = (const int *)pv.buf;
    S->n_cc = head[0]; S->n_cb = head[1]; S->n_bb = head[2];
    PyBuffer_Release(&pv);
    Py_ssize_t np_ = (Py_ssize_t)(S->n_cc + S->n_cb + S->n_bb);
    if (n_pairs_items != 3 + 2 * np_) { PyErr_SetString(PyExc_ValueError, "_guard.Scene: pairs: wrong size"); return -1; }
    S->n_arms = n_arms;
    int *all_pairs = NULL;
    if (copy_buffer(arm, "d", 8, (Py_ssize_t)n_arms * ARM_DOUBLES, (void **)&S->arm, "arm_data") < 0) return -1;
    if (copy_buffer(caps_i, "il", 4, (Py_ssize_t)S->n_caps * 3, (void **)&S->caps_i, "caps_i") < 0) return -1;
    if (copy_buffer(caps_r, "d", 8, S->n_caps, (void **)&S->caps_r, "caps_r") < 0) return -1;
    if (copy_buffer(boxes_i, "il", 4, S->n_boxes, (void **)&S->boxes_i, "boxes_i") < 0) return -1;
    if (copy_buffer(boxes_d, "d", 8, (Py_ssize_t)S->n_boxes * BOX_DOUBLES, (void **)&S->boxes_d, "boxes_d") < 0) return -1;
    if (copy_buffer(pairs, "il", 4, n_pairs_items, (void **)&all_pairs, "pairs") < 0) return -1;
    S->pairs = malloc(sizeof(int) * (size_t)(2 * np_ + 1));
    if (S->pairs == NULL) { free(all_pairs); PyErr_NoMemory(); return -1; }
    memcpy(S->pairs, all_pairs + 3, sizeof(int) * (size_t)(2 * np_));
    free(all_pairs);
    for (int c = 0; c < S->n_caps; c++) {
        int a = S->caps_i[c * 3], e0 = S->caps_i[c * 3 + 1], e1 = S->caps_i[c * 3 + 2];
        if (a < 0 || a >= n_arms || e0 < 0 || e0 > 7 || e1 < 0 || e1 > 7) {
            PyErr_SetString(PyExc_ValueError, "_guard.Scene: caps_i: index out of range"); return -1;
        }
    }
    for (int k = 0; k < S->n_boxes; k++)
        if (S->boxes_i[k] < -1 || S->boxes_i[k] >= n_arms) { PyErr_SetString(PyExc_ValueError, "_guard.Scene: boxes_i"); return -1; }
    const int *p = S->pairs;
    for (Py_ssize_t i = 0; i < np_; i++, p += 2) {
        int lim0 = i < S->n_cc + S->n_cb ? S->n_caps : S->n_boxes;
        int lim1 = i < S->n_cc ? S->n_caps : S->n_boxes;
        if (p[0] < 0 || p[0] >= lim0 || p[1] < 0 || p[1] >= lim1) {
            PyErr_SetString(PyExc_ValueError, "_guard.Scene: pairs: index out of range"); return -1;
        }
    }
    S->pts = malloc(sizeof(double) * (size_t)n_arms * 24);
    S->tool0 = malloc(sizeof(double) * (size_t)n_arms * 16);
    S->bc = malloc(sizeof(double) * (size_t)(S->n_boxes * 3 + 1));
    S->bR = malloc(sizeof(double) * (size_t)(S->n_boxes * 9 + 1));
    if (!S->pts || !S->tool0 || !S->bc || !S->bR) { PyErr_NoMemory(); return -1; }
    return 0;
}

static int writable(PyObject *o, Py_buffer *view) {
    return PyObject_GetBuffer(o, view, PyBUF_C_CONTIGUOUS | PyBUF_WRITABLE);
}

/* distances(q, out) and closest(q, out, pa, pb): B configurations, one pass each */
static PyObject *scene_call(Scene *S, PyObject *args, int points) {
    PyObject *qo, *oo, *ao = NULL, *bo = NULL;
    if (points ? !PyArg_ParseTuple(args, "OOOO", &qo, &oo, &ao, &bo) : !PyArg_ParseTuple(args, "OO", &qo, &oo)) return NULL;
    Py_buffer q, out, va, vb;
    if (PyObject_GetBuffer(qo, &q, PyBUF_C_CONTIGUOUS) < 0) return NULL;
    if (writable(oo, &out) < 0) { PyBuffer_Release(&q); return NULL; }
    if (points && writable(ao, &va) < 0) { PyBuffer_Release(&q); PyBuffer_Release(&out); return NULL; }
    if (points && writable(bo, &vb) < 0) { PyBuffer_Release(&q); PyBuffer_Release(&out); PyBuffer_Release(&va); return NULL; }
    Py_ssize_t per_q = (Py_ssize_t)S->n_arms * 6, n_pairs = (Py_ssize_t)(S->n_cc + S->n_cb + S->n_bb);
    Py_ssize_t B = q.len / (Py_ssize_t)sizeof(double) / per_q;
    Py_ssize_t need = B * n_pairs * (Py_ssize_t)sizeof(double);
    int bad = q.len != B * per_q * (Py_ssize_t)sizeof(double) || out.len < need
              || (points && (va.len < 3 * need || vb.len < 3 * need));
    if (!bad) {
        const double *qd = (const double *)q.buf;
        double *od = (double *)out.buf, *ad = points ? (double *)va.buf : NULL, *bd = points ? (double *)vb.buf : NULL;
        for (Py_ssize_t b = 0; b < B; b++)
            scene_pass(S, qd + b * per_q, od + b * n_pairs, points ? ad + b * n_pairs * 3 : NULL,
                       points ? bd + b * n_pairs * 3 : NULL);
    }
    PyBuffer_Release(&q);
    PyBuffer_Release(&out);
    if (points) { PyBuffer_Release(&va); PyBuffer_Release(&vb); }
    if (bad) {
        PyErr_SetString(PyExc_ValueError, points ? "_guard.Scene.closest: q must hold B * n_arms * 6 doubles, out B * n_pairs, pa and pb B * n_pairs * 3"
                                                 : "_guard.Scene.distances: q must hold B * n_arms * 6 doubles, out B * n_pairs");
        return NULL;
    }
    Py_RETURN_NONE;
}

/* poses(q, p0, p1, bc, bR): the bodies' poses for B configurations */
static PyObject *Scene_poses(Scene *S, PyObject *args) {
    PyObject *qo, *o[4];
    if (!PyArg_ParseTuple(args, "OOOOO", &qo, &o[0], &o[1], &o[2], &o[3])) return NULL;
    Py_buffer q, v[4];
    if (PyObject_GetBuffer(qo, &q, PyBUF_C_CONTIGUOUS) < 0) return NULL;
    int got = 0;
    for (; got < 4; got++)
        if (writable(o[got], &v[got]) < 0) break;
    Py_ssize_t per_q = (Py_ssize_t)S->n_arms * 6, d = (Py_ssize_t)sizeof(double);
    Py_ssize_t B = q.len / d / per_q;
    int bad = got < 4 || q.len != B * per_q * d || v[0].len < B * S->n_caps * 3 * d || v[1].len < B * S->n_caps * 3 * d
              || v[2].len < B * S->n_boxes * 3 * d || v[3].len < B * S->n_boxes * 9 * d;
    if (!bad) {
        const double *qd = (const double *)q.buf;
        double *p0 = (double *)v[0].buf, *p1 = (double *)v[1].buf, *bc = (double *)v[2].buf, *bR = (double *)v[3].buf;
        for (Py_ssize_t b = 0; b < B; b++) {
            scene_fk(S, qd + b * per_q);
            for (int c = 0; c < S->n_caps; c++) {
                const int *ci = S->caps_i + c * 3;
                const double *P = S->pts + ci[0] * 24;
                memcpy(p0 + (b * S->n_caps + c) * 3, P + ci[1] * 3, 3 * sizeof(double));
                memcpy(p1 + (b * S->n_caps + c) * 3, P + ci[2] * 3, 3 * sizeof(double));
            }
            memcpy(bc + b * S->n_boxes * 3, S->bc, (size_t)S->n_boxes * 3 * sizeof(double));
            memcpy(bR + b * S->n_boxes * 9, S->bR, (size_t)S->n_boxes * 9 * sizeof(double));
        }
    }
    PyBuffer_Release(&q);
    for (int i = 0; i < got; i++) PyBuffer_Release(&v[i]);
    if (bad) {
        if (!PyErr_Occurred())
            PyErr_SetString(PyExc_ValueError, "_guard.Scene.poses: q must hold B * n_arms * 6 doubles, p0 and p1 B * n_caps * 3, "
                                              "bc B * n_boxes * 3, bR B * n_boxes * 9");
        return NULL;
    }
    Py_RETURN_NONE;
}

static PyObject *Scene_distances(Scene *S, PyObject *args) { return scene_call(S, args, 0); }
static PyObject *Scene_closest(Scene *S, PyObject *args) { return scene_call(S, args, 1); }

static PyMethodDef Scene_methods[] = {
    {"distances", (PyCFunction)Scene_distances, METH_VARARGS,
     "distances(q, out): every pair's distance [mm] for B joint configurations [deg]"},
    {"closest", (PyCFunction)Scene_closest, METH_VARARGS,
     "closest(q, out, pa, pb): the distances and every pair's closest points [mm, global]"},
    {"poses", (PyCFunction)Scene_poses, METH_VARARGS,
     "poses(q, p0, p1, bc, bR): the capsules' ends and the boxes' frames [mm, global]"},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject SceneType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "droid._guard.Scene",
    .tp_basicsize = sizeof(Scene),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "A cell's bodies and checked pairs, for the compiled distance pass (droid.guard.kernel)",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Scene_init,
    .tp_dealloc = (destructor)Scene_dealloc,
    .tp_methods = Scene_methods,
};

static struct PyModuleDef guardmodule = {PyModuleDef_HEAD_INIT, "_guard",
                                         "The collision guard's distance pass, compiled (docs/guard.md)", -1, NULL};

PyMODINIT_FUNC PyInit__guard(void) {
    init_edges();
    if (PyType_Ready(&SceneType) < 0) return NULL;
    PyObject *m = PyModule_Create(&guardmodule);
    if (m == NULL) return NULL;
    Py_INCREF(&SceneType);
    if (PyModule_AddObject(m, "Scene", (PyObject *)&SceneType) < 0) { Py_DECREF(&SceneType); Py_DECREF(m); return NULL; }
    PyModule_AddIntConstant(m, "ARM_DOUBLES", ARM_DOUBLES);
    return m;
}
