/*
 * _zhang_terms: the per-pixel terms of the authors' Zhang method (``--parity upstream``, see upstream.py), sorted,
 * bit for bit what the numpy path of upstream.py computes (and so the authors' scipy/numpy code):
 *
 *   Ix, Iy = Scharr gradients of the gray codes (exact integers), Jx, Jy = Scharr gradients of J = jlut[gray]
 *   (float64, the products of the kernel taken row by row and added in that order, as scipy.signal.convolve2d;
 *   symmetric boundary), term = 2 (Ix Jx + Iy Jy) in long double, then the terms sorted ascending.
 *
 * Built with -ffp-contract=off (no fused multiply-add: every product and sum is rounded as numpy rounds it).
 * The sort: an LSD radix sort of (float64 rounding as an ordered 64-bit key, exact long-double residual as a
 * double), then runs of equal keys sorted by their residual, so the output equals numpy's sort of the long doubles.
 * weighted_sum goes on to the method's sum np.sum(w * terms) (float32 weights), in numpy's pairwise order with
 * long-double accumulators, without writing the sorted terms out. The GIL is released while they run.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

typedef struct {
    uint64_t key;
    double lo;
} rec_t;

static inline uint64_t order_key(double hi)
{
    uint64_t bits;
    if (isnan(hi)) {
        return UINT64_MAX; /* numpy sorts NaN last */
    }
    memcpy(&bits, &hi, sizeof bits);
    return (bits & 0x8000000000000000ull) ? ~bits : (bits | 0x8000000000000000ull);
}

static inline double key_value(uint64_t key)
{
    uint64_t bits = (key & 0x8000000000000000ull) ? (key & 0x7fffffffffffffffull) : ~key;
    double v;
    memcpy(&v, &bits, sizeof v);
    return v;
}

static inline Py_ssize_t refl(Py_ssize_t i, Py_ssize_t n)
{
    /* symmetric boundary for a 3x3 kernel: -1 -> 0, n -> n - 1 */
    return i < 0 ? 0 : (i >= n ? n - 1 : i);
}

/* the terms of row y into recs[y * w ...] */
static void terms_rows(const uint16_t *g, const double *jlut, Py_ssize_t h, Py_ssize_t w, rec_t *recs)
{
    for (Py_ssize_t y = 0; y < h; y++) {
        /* convolution: out(y, x) = sum K[r][c] * in(y + 1 - r, x + 1 - c), r and c row by row */
        const uint16_t *r0 = g + refl(y + 1, h) * w; /* r = 0 */
        const uint16_t *r1 = g + y * w;              /* r = 1 */
        const uint16_t *r2 = g + refl(y - 1, h) * w; /* r = 2 */
        for (Py_ssize_t x = 0; x < w; x++) {
            Py_ssize_t xp = refl(x + 1, w), xm = refl(x - 1, w); /* c = 0 -> x + 1, c = 2 -> x - 1 */
            /* Scharr x: [[3, 0, -3], [10, 0, -10], [3, 0, -3]]; Scharr y: [[3, 10, 3], [0, 0, 0], [-3, -10, -3]] */
            long ix = 3L * r0[xp] - 3L * r0[xm] + 10L * r1[xp] - 10L * r1[xm] + 3L * r2[xp] - 3L * r2[xm];
            long iy = 3L * r0[xp] + 10L * r0[x] + 3L * r0[xm] - 3L * r2[xp] - 10L * r2[x] - 3L * r2[xm];
            double a = jlut[r0[xp]], b = jlut[r0[x]], c = jlut[r0[xm]];
            double d = jlut[r1[xp]], f = jlut[r1[xm]];
            double p = jlut[r2[xp]], q = jlut[r2[x]], s = jlut[r2[xm]];
            double jx = a * 3.0;
            jx = jx + c * -3.0;
            jx = jx + d * 10.0;
            jx = jx + f * -10.0;
            jx = jx + p * 3.0;
            jx = jx + s * -3.0;
            double jy = a * 3.0;
            jy = jy + b * 10.0;
            jy = jy + c * 3.0;
            jy = jy + p * -3.0;
            jy = jy + q * -10.0;
            jy = jy + s * -3.0;
            long double t1 = (long double)ix * (long double)jx;
            long double t2 = (long double)iy * (long double)jy;
            long double t = t1 + t2;
            t = t * 2.0L;
            double hi = (double)t;
            rec_t *out = recs + y * w + x;
            out->key = order_key(hi);
            out->lo = isfinite(hi) ? (double)(t - (long double)hi) : 0.0;
        }
    }
}

/* 8-bit digits: 256 output streams per pass stay in the caches (11-bit digits, 2048 streams, two passes fewer, were
   ~1.5x slower here) */
#define DIGIT_BITS 8
#define N_BUCKETS (1u << DIGIT_BITS)
#define N_PASSES 8 /* 64 bits */

static int radix_sort(rec_t *a, size_t n)
{
    rec_t *tmp = (rec_t *)malloc(n * sizeof(rec_t));
    size_t(*hist)[N_BUCKETS] = calloc(N_PASSES, sizeof *hist);
    if (tmp == NULL || hist == NULL) {
        free(tmp);
        free(hist);
        return -1;
    }
    for (size_t i = 0; i < n; i++) {
        uint64_t k = a[i].key;
        for (int p = 0; p < N_PASSES; p++) {
            hist[p][(k >> (p * DIGIT_BITS)) & (N_BUCKETS - 1)]++;
        }
    }
    rec_t *src = a, *dst = tmp;
    for (int p = 0; p < N_PASSES; p++) {
        size_t *hp = hist[p];
        int trivial = 0;
        for (unsigned b = 0; b < N_BUCKETS; b++) {
            if (hp[b] == n) {
                trivial = 1;
                break;
            }
        }
        if (trivial) {
            continue; /* every key has the same digit */
        }
        size_t sum = 0;
        for (unsigned b = 0; b < N_BUCKETS; b++) {
            size_t c = hp[b];
            hp[b] = sum;
            sum += c;
        }
        int shift = p * DIGIT_BITS;
        for (size_t i = 0; i < n; i++) {
            dst[hp[(src[i].key >> shift) & (N_BUCKETS - 1)]++] = src[i];
        }
        rec_t *t = src;
        src = dst;
        dst = t;
    }
    if (src != a) {
        memcpy(a, src, n * sizeof(rec_t));
    }
    free(tmp);
    free(hist);
    return 0;
}

static void runs_by_residual(rec_t *a, size_t n)
{
    size_t i = 0;
    while (i < n) {
        size_t j = i + 1;
        while (j < n && a[j].key == a[i].key) {
            j++;
        }
        if (j - i > 1) { /* insertion sort of the run by residual (runs are short) */
            for (size_t u = i + 1; u < j; u++) {
                rec_t r = a[u];
                size_t v = u;
                while (v > i && a[v - 1].lo > r.lo) {
                    a[v] = a[v - 1];
                    v--;
                }
                a[v] = r;
            }
        }
        i = j;
    }
}

/* the sorted terms as long doubles (NaN stays NaN) */
static inline long double term_value(const rec_t *r)
{
    double hi = key_value(r->key);
    return isnan(hi) ? (long double)NAN : (long double)hi + (long double)r->lo;
}

/* numpy's pairwise sum (long double accumulators: blocks of at most 128 summed by 8 accumulators, halves at
   multiples of 8) of the products weights[i] * term[i], each rounded to long double as numpy's w * terms */
static long double weighted_pairwise(const rec_t *r, const float *wt, size_t n)
{
    if (n < 8) {
        long double res = 0.0L;
        for (size_t i = 0; i < n; i++) {
            res += (long double)wt[i] * term_value(r + i);
        }
        return res;
    }
    if (n <= 128) {
        long double acc[8];
        for (int j = 0; j < 8; j++) {
            acc[j] = (long double)wt[j] * term_value(r + j);
        }
        size_t i = 8;
        for (; i < n - (n % 8); i += 8) {
            for (int j = 0; j < 8; j++) {
                acc[j] += (long double)wt[i + j] * term_value(r + i + j);
            }
        }
        long double res = ((acc[0] + acc[1]) + (acc[2] + acc[3])) + ((acc[4] + acc[5]) + (acc[6] + acc[7]));
        for (; i < n; i++) {
            res += (long double)wt[i] * term_value(r + i);
        }
        return res;
    }
    size_t n2 = n / 2;
    n2 -= n2 % 8;
    return weighted_pairwise(r, wt, n2) + weighted_pairwise(r + n2, wt + n2, n - n2);
}

/* the terms of the image, sorted into recs (n = h * w records); -1 when out of memory */
static int sorted_records(const uint16_t *gray, const double *jlut, Py_ssize_t h, Py_ssize_t w, rec_t *recs)
{
    terms_rows(gray, jlut, h, w, recs);
    if (radix_sort(recs, (size_t)h * (size_t)w) != 0) {
        return -1;
    }
    runs_by_residual(recs, (size_t)h * (size_t)w);
    return 0;
}

static PyObject *sorted_terms(PyObject *self, PyObject *args)
{
    Py_buffer gray, jlut, out;
    Py_ssize_t h, w;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*nnw*", &gray, &jlut, &h, &w, &out)) {
        return NULL;
    }
    const char *error = NULL;
    size_t n = (size_t)h * (size_t)w;
    if (h < 1 || w < 1) {
        error = "the image must be at least 1x1";
    } else if (gray.len != (Py_ssize_t)(n * sizeof(uint16_t))) {
        error = "gray must be a C-contiguous uint16 HxW buffer";
    } else if (jlut.len != (Py_ssize_t)(65536 * sizeof(double))) {
        error = "jlut must hold 65536 float64 entries";
    } else if (out.len != (Py_ssize_t)(n * sizeof(long double))) {
        error = "out must be a long double buffer of H*W entries";
    }
    int failed = 0;
    if (error == NULL) {
        Py_BEGIN_ALLOW_THREADS
        rec_t *recs = (rec_t *)malloc(n * sizeof(rec_t));
        if (recs == NULL || sorted_records((const uint16_t *)gray.buf, (const double *)jlut.buf, h, w, recs) != 0) {
            failed = 1;
        } else {
            long double *o = (long double *)out.buf;
            for (size_t i = 0; i < n; i++) {
                o[i] = term_value(recs + i);
            }
        }
        free(recs);
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&gray);
    PyBuffer_Release(&jlut);
    PyBuffer_Release(&out);
    if (error != NULL) {
        PyErr_SetString(PyExc_ValueError, error);
        return NULL;
    }
    if (failed) {
        return PyErr_NoMemory();
    }
    Py_RETURN_NONE;
}

static PyObject *weighted_sum(PyObject *self, PyObject *args)
{
    Py_buffer gray, jlut, weights, out;
    Py_ssize_t h, w;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*nny*w*", &gray, &jlut, &h, &w, &weights, &out)) {
        return NULL;
    }
    const char *error = NULL;
    size_t n = (size_t)h * (size_t)w;
    if (h < 1 || w < 1) {
        error = "the image must be at least 1x1";
    } else if (gray.len != (Py_ssize_t)(n * sizeof(uint16_t))) {
        error = "gray must be a C-contiguous uint16 HxW buffer";
    } else if (jlut.len != (Py_ssize_t)(65536 * sizeof(double))) {
        error = "jlut must hold 65536 float64 entries";
    } else if (weights.len != (Py_ssize_t)(n * sizeof(float))) {
        error = "weights must be float32 (H*W,)";
    } else if (out.len != (Py_ssize_t)sizeof(long double)) {
        error = "out must be a long double buffer of 1 entry";
    }
    int failed = 0;
    if (error == NULL) {
        Py_BEGIN_ALLOW_THREADS
        rec_t *recs = (rec_t *)malloc(n * sizeof(rec_t));
        if (recs == NULL || sorted_records((const uint16_t *)gray.buf, (const double *)jlut.buf, h, w, recs) != 0) {
            failed = 1;
        } else {
            *(long double *)out.buf = 0.0L + weighted_pairwise(recs, (const float *)weights.buf, n);
        }
        free(recs);
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&gray);
    PyBuffer_Release(&jlut);
    PyBuffer_Release(&weights);
    PyBuffer_Release(&out);
    if (error != NULL) {
        PyErr_SetString(PyExc_ValueError, error);
        return NULL;
    }
    if (failed) {
        return PyErr_NoMemory();
    }
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"sorted_terms", sorted_terms, METH_VARARGS,
     "sorted_terms(gray, jlut, h, w, out): the authors' Zhang terms 2 (Ix Jx + Iy Jy), sorted, into out (long "
     "double, H*W); gray: C-contiguous uint16 HxW codes, jlut: 65536 float64 (J per code)."},
    {"weighted_sum", weighted_sum, METH_VARARGS,
     "weighted_sum(gray, jlut, h, w, weights, out): np.sum(weights * sorted terms) into out (long double (1,)), bit "
     "for bit (numpy's pairwise sum of the long-double products); weights: float32 (H*W,)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_zhang_terms", "The authors' Zhang terms, sorted.", -1,
                                    methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__zhang_terms(void)
{
    return PyModule_Create(&module);
}
