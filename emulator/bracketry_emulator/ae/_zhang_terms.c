/*
 * _zhang_terms: the per-pixel terms of the authors' Zhang method (``--parity upstream``, see upstream.py), sorted,
 * bit for bit what the numpy path of upstream.py computes (and so the authors' scipy/numpy code):
 *
 *   Ix, Iy = Scharr gradients of the gray codes (exact integers), Jx, Jy = Scharr gradients of J = jlut[gray]
 *   (float64, the products of the kernel taken row by row and added in that order, as scipy.signal.convolve2d;
 *   symmetric boundary), term = 2 (Ix Jx + Iy Jy) in long double, then the terms sorted ascending.
 *
 * Built with -ffp-contract=off (no fused multiply-add: every product and sum is rounded as numpy rounds it).
 * Each term is a record (its float64 rounding as an ordered 64-bit key, the exact long-double residual as a double);
 * sorting the records by (key, residual) orders the long doubles as numpy's sort does. The sort is a most-significant
 * digit radix sort (see msd_sort); weighted_sum goes on to the method's sum np.sum(w * terms) (float32 weights), in
 * numpy's pairwise order with long-double accumulators, sorting each bucket just before the sum reads it and
 * without writing the sorted terms out. The scratch memory is kept between calls. The GIL is released while they
 * run.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#if defined(__SSE2__) && defined(__x86_64__)
#include <emmintrin.h>
#endif

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

#define TOP_BITS 16 /* the sort's first digit (see msd_sort) */
#define N_TOP (1u << TOP_BITS)
#define SMALL_RUN 32 /* insertion sort up to this many records */

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__)
/* compiled for AVX2 and for the baseline, chosen at load time (no FMA: the same IEEE operations in both) */
#define MULTIVERSION __attribute__((target_clones("avx2", "default")))
#else
#define MULTIVERSION
#endif

static inline Py_ssize_t refl(Py_ssize_t i, Py_ssize_t n)
{
    /* symmetric boundary for a 3x3 kernel: -1 -> 0, n -> n - 1 */
    return i < 0 ? 0 : (i >= n ? n - 1 : i);
}

/* recs are written once and read back by the scatter long after they left the caches: streaming stores (no read
   of the destination's lines first) where the compiler has them */
static inline void store_record(rec_t *r, uint64_t key, double lo)
{
#if defined(__SSE2__) && defined(__x86_64__)
    long long k, l;
    memcpy(&k, &key, sizeof k);
    memcpy(&l, &lo, sizeof l);
    _mm_stream_si64((long long *)&r->key, k);
    _mm_stream_si64((long long *)&r->lo, l);
#else
    r->key = key;
    r->lo = lo;
#endif
}

/* one image row, padded by the symmetric boundary (p[0] = value at x = 0, p[x + 1] = value at x, p[w + 1] = value
   at x = w - 1): the codes as int32 and J = jlut[code] */
static void padded_row(const uint16_t *g, const double *jlut, Py_ssize_t w, int32_t *ip, double *jp)
{
    for (Py_ssize_t x = 0; x < w; x++) {
        ip[x + 1] = g[x];
        jp[x + 1] = jlut[g[x]];
    }
    ip[0] = ip[1];
    jp[0] = jp[1];
    ip[w + 1] = ip[w];
    jp[w + 1] = jp[w];
}

/* the gradients of one output row from its padded rows (0: y + 1, 1: y, 2: y - 1, the convolution's kernel rows
   r = 0, 1, 2): Ix, Iy exact integers, Jx, Jy float64 with the products added in the kernel's row-by-row order.
   convolution: out(y, x) = sum K[r][c] * in(y + 1 - r, x + 1 - c); c = 0 -> x + 1 (padded x + 2), c = 2 -> x - 1
   (padded x). Scharr x: [[3, 0, -3], [10, 0, -10], [3, 0, -3]]; Scharr y: [[3, 10, 3], [0, 0, 0], [-3, -10, -3]] */
MULTIVERSION
static void gradient_row(const int32_t *restrict i0, const int32_t *restrict i1, const int32_t *restrict i2,
                         const double *restrict j0, const double *restrict j1, const double *restrict j2,
                         Py_ssize_t w, int32_t *restrict ix, int32_t *restrict iy, double *restrict jx,
                         double *restrict jy)
{
    for (Py_ssize_t x = 0; x < w; x++) {
        ix[x] = 3 * i0[x + 2] - 3 * i0[x] + 10 * i1[x + 2] - 10 * i1[x] + 3 * i2[x + 2] - 3 * i2[x];
        iy[x] = 3 * i0[x + 2] + 10 * i0[x + 1] + 3 * i0[x] - 3 * i2[x + 2] - 10 * i2[x + 1] - 3 * i2[x];
        double a = j0[x + 2], b = j0[x + 1], c = j0[x];
        double d = j1[x + 2], f = j1[x];
        double p = j2[x + 2], q = j2[x + 1], s = j2[x];
        double gx = a * 3.0;
        gx = gx + c * -3.0;
        gx = gx + d * 10.0;
        gx = gx + f * -10.0;
        gx = gx + p * 3.0;
        gx = gx + s * -3.0;
        double gy = a * 3.0;
        gy = gy + b * 10.0;
        gy = gy + c * 3.0;
        gy = gy + p * -3.0;
        gy = gy + q * -10.0;
        gy = gy + s * -3.0;
        jx[x] = gx;
        jy[x] = gy;
    }
}

/* the terms of the image into recs (row-major), counts[k] += 1 for each record whose key's top TOP_BITS bits are
   k; rows: scratch of 3 * (w + 2) int32 + 3 * (w + 2) float64 + 2 * w int32 + 2 * w float64 */
static void terms_rows(const uint16_t *g, const double *jlut, Py_ssize_t h, Py_ssize_t w, rec_t *recs,
                       size_t *counts, void *rows)
{
    double *jp = (double *)rows;          /* 3 padded J rows */
    double *jx = jp + 3 * (w + 2), *jy = jx + w;
    int32_t *ip = (int32_t *)(jy + w);    /* 3 padded code rows */
    int32_t *ix = ip + 3 * (w + 2), *iy = ix + w;
    Py_ssize_t held[3] = {-1, -1, -1}; /* the image row in each slot (slot = row % 3) */
    for (Py_ssize_t y = 0; y < h; y++) {
        Py_ssize_t want[3] = {refl(y + 1, h), y, refl(y - 1, h)};
        for (int r = 0; r < 3; r++) {
            Py_ssize_t slot = want[r] % 3;
            if (held[slot] != want[r]) {
                padded_row(g + want[r] * w, jlut, w, ip + slot * (w + 2), jp + slot * (w + 2));
                held[slot] = want[r];
            }
        }
        Py_ssize_t s0 = want[0] % 3, s1 = want[1] % 3, s2 = want[2] % 3;
        gradient_row(ip + s0 * (w + 2), ip + s1 * (w + 2), ip + s2 * (w + 2), jp + s0 * (w + 2),
                     jp + s1 * (w + 2), jp + s2 * (w + 2), w, ix, iy, jx, jy);
        rec_t *out = recs + y * w;
        for (Py_ssize_t x = 0; x < w; x++) {
            long double t1 = (long double)ix[x] * (long double)jx[x];
            long double t2 = (long double)iy[x] * (long double)jy[x];
            long double t = t1 + t2;
            t = t * 2.0L;
            double hi = (double)t;
            uint64_t key = order_key(hi);
            double lo = isfinite(hi) ? (double)(t - (long double)hi) : 0.0;
            store_record(out + x, key, lo);
            counts[key >> (64 - TOP_BITS)]++;
        }
    }
#if defined(__SSE2__) && defined(__x86_64__)
    _mm_sfence();
#endif
}

/* The sort (ascending by key, then by residual: the order of the long doubles; equal records are equal values), a
 * most-significant-digit radix sort: the top TOP_BITS bits of the key (sign, exponent, 4 mantissa bits; counted
 * while the terms are computed) spread the records over their buckets (~1300 of ~2000 records on a 1920x1200 frame
 * here), and each bucket is then sorted on its own while it sits in the caches (msd_sort), just before the weighted
 * sum reads it. The LSD radix sort this replaces (8 passes of 8-bit digits over 37 MB of records) was memory-bound
 * and ~2x slower here. */

static inline int rec_less(const rec_t *a, const rec_t *b)
{
    return a->key < b->key || (a->key == b->key && a->lo < b->lo);
}

static void insertion_sort(rec_t *a, size_t n)
{
    for (size_t u = 1; u < n; u++) {
        rec_t r = a[u];
        size_t v = u;
        while (v > 0 && rec_less(&r, &a[v - 1])) {
            a[v] = a[v - 1];
            v--;
        }
        a[v] = r;
    }
}

#define MAX_BITS 14 /* at most 2^14 sub-buckets per split */
#define MAX_DEPTH 8 /* splits of >= 6 bits (n > SMALL_RUN) below the top digit: at most 48 / 6 levels */

/* sorts a[0..n) in place, n > SMALL_RUN, all keys equal above bit `top` (top + 1 bits left to sort, top >= 0);
   buf: scratch of n records. One radix split on the next ~log2(n) bits of the key, at most MAX_BITS (the keys of a
   bucket are nearly uniform there: ~1 record per sub-bucket), sub-buckets of more than SMALL_RUN records split again, then one
   insertion pass over the whole, nearly sorted, run (which also orders equal keys by their residuals).
   counts: MAX_DEPTH * (2^MAX_BITS + 1) counters (this level's and the deeper levels'); n < 2^32. */
static void msd_sort(rec_t *a, rec_t *buf, size_t n, int top, uint32_t *counts)
{
    int bits = 1;
    while (bits < MAX_BITS && ((size_t)1 << bits) < n) {
        bits++;
    }
    for (;;) {
        if (bits > top + 1) {
            bits = top + 1;
        }
        int shift = top + 1 - bits;
        uint64_t mask = ((uint64_t)1 << bits) - 1;
        uint32_t *start = counts;
        size_t nb = (size_t)1 << bits;
        memset(start, 0, (nb + 1) * sizeof start[0]);
        for (size_t i = 0; i < n; i++) {
            start[((a[i].key >> shift) & mask) + 1]++;
        }
        if (start[((a[0].key >> shift) & mask) + 1] == n) { /* every key has the same digit */
            if (shift == 0) {
                insertion_sort(a, n); /* equal keys: by residual (equal records do not move) */
                return;
            }
            top = shift - 1;
            continue;
        }
        int big = 0;
        for (size_t b = 0; b < nb; b++) {
            big |= start[b + 1] > SMALL_RUN;
            start[b + 1] += start[b];
        }
        for (size_t i = 0; i < n; i++) {
            buf[start[(a[i].key >> shift) & mask]++] = a[i]; /* start[b] ends at the start of b + 1 */
        }
        if (big && shift > 0) {
            size_t lo = 0;
            for (size_t b = 0; b < nb; b++) {
                size_t hi = start[b];
                if (hi - lo > SMALL_RUN) {
                    msd_sort(buf + lo, a + lo, hi - lo, shift - 1, counts + ((size_t)1 << MAX_BITS) + 1);
                }
                lo = hi;
            }
        }
        insertion_sort(buf, n);
        memcpy(a, buf, n * sizeof(rec_t));
        return;
    }
}

/* Reused between calls (the ~74 MB of records and the counts would otherwise be fresh pages each step); one
   thread at a time takes it, another concurrent caller allocates its own. */
typedef struct {
    size_t capacity; /* records in each of recs and sorted */
    rec_t *recs;
    rec_t *sorted;
    size_t *top; /* N_TOP + 1 bucket starts in sorted */
    rec_t *aux;  /* scratch of the largest bucket (stays in the caches) */
    size_t aux_capacity;
    void *rows; /* terms_rows's row buffers */
    size_t rows_bytes;
    uint32_t *counts; /* msd_sort's */
} scratch_t;

static scratch_t *cached_scratch = NULL;

static void scratch_free(scratch_t *s)
{
    if (s != NULL) {
        free(s->recs);
        free(s->sorted);
        free(s->top);
        free(s->aux);
        free(s->rows);
        free(s->counts);
        free(s);
    }
}

static scratch_t *scratch_take(size_t n)
{
    scratch_t *s = __atomic_exchange_n(&cached_scratch, NULL, __ATOMIC_ACQ_REL);
    if (s != NULL && s->capacity >= n) {
        return s;
    }
    scratch_free(s);
    s = (scratch_t *)calloc(1, sizeof *s);
    if (s == NULL) {
        return NULL;
    }
    s->capacity = n;
    s->recs = (rec_t *)malloc(n * sizeof(rec_t));
    s->sorted = (rec_t *)malloc(n * sizeof(rec_t));
    s->top = (size_t *)malloc((N_TOP + 1) * sizeof(size_t));
    s->counts = (uint32_t *)malloc(MAX_DEPTH * (((size_t)1 << MAX_BITS) + 1) * sizeof(uint32_t));
    if (s->recs == NULL || s->sorted == NULL || s->top == NULL || s->counts == NULL) {
        scratch_free(s);
        return NULL;
    }
    return s;
}

static void scratch_give(scratch_t *s)
{
    scratch_t *old = __atomic_exchange_n(&cached_scratch, s, __ATOMIC_ACQ_REL);
    scratch_free(old);
}

/* the records spread over their top buckets (s->sorted, bucket b at s->top[b] .. s->top[b + 1]), each bucket
   still unsorted; sorted_upto / next_bucket: how far the buckets are sorted */
typedef struct {
    scratch_t *s;
    size_t n, sorted_upto;
    unsigned next_bucket;
} spread_t;

/* -1 when out of memory */
static int spread_terms(const uint16_t *gray, const double *jlut, Py_ssize_t h, Py_ssize_t w, scratch_t *s,
                        spread_t *sp)
{
    size_t n = (size_t)h * (size_t)w;
    size_t *top = s->top;
    size_t rows_bytes = (size_t)(5 * w + 6) * (sizeof(double) + sizeof(int32_t));
    if (rows_bytes > s->rows_bytes) {
        free(s->rows);
        s->rows = malloc(rows_bytes);
        s->rows_bytes = s->rows == NULL ? 0 : rows_bytes;
        if (s->rows == NULL) {
            return -1;
        }
    }
    memset(top, 0, (N_TOP + 1) * sizeof(size_t));
    terms_rows(gray, jlut, h, w, s->recs, top + 1, s->rows);
    size_t largest = 0;
    for (unsigned b = 0; b < N_TOP; b++) { /* counts at top[b + 1] -> starts */
        largest = top[b + 1] > largest ? top[b + 1] : largest;
        top[b + 1] += top[b];
    }
    if (largest > s->aux_capacity) {
        free(s->aux);
        s->aux = (rec_t *)malloc(largest * sizeof(rec_t));
        s->aux_capacity = s->aux == NULL ? 0 : largest;
        if (s->aux == NULL) {
            return -1;
        }
    }
    /* scatter with top[b] as the running cursor, then shift the starts back */
    for (size_t i = 0; i < n; i++) {
        const rec_t *r = s->recs + i;
        s->sorted[top[r->key >> (64 - TOP_BITS)]++] = *r;
    }
    for (unsigned b = N_TOP; b > 0; b--) {
        top[b] = top[b - 1];
    }
    top[0] = 0;
    sp->s = s;
    sp->n = n;
    sp->sorted_upto = 0;
    sp->next_bucket = 0;
    return 0;
}

/* sorts the buckets until the first `end` records are in their final order */
static void sort_upto(spread_t *sp, size_t end)
{
    scratch_t *s = sp->s;
    while (sp->sorted_upto < end && sp->next_bucket < N_TOP) {
        unsigned b = sp->next_bucket++;
        size_t a = s->top[b], c = s->top[b + 1] - a;
        if (c > SMALL_RUN) {
            msd_sort(s->sorted + a, s->aux, c, 63 - TOP_BITS, s->counts);
        } else if (c > 1) {
            insertion_sort(s->sorted + a, c);
        }
        sp->sorted_upto = a + c;
    }
}

/* the sorted terms as long doubles (NaN stays NaN) */
static inline long double term_value(const rec_t *r)
{
    double hi = key_value(r->key);
    return isnan(hi) ? (long double)NAN : (long double)hi + (long double)r->lo;
}

/* numpy's pairwise sum (long double accumulators: blocks of at most 128 summed by 8 accumulators, halves at
   multiples of 8) of the products weights[i] * term[i0 + i], each rounded to long double as numpy's w * terms; the
   buckets are sorted as the blocks reach them */
static long double weighted_pairwise(spread_t *sp, size_t i0, const float *wt, size_t n)
{
    if (n > 128) {
        size_t n2 = n / 2;
        n2 -= n2 % 8;
        return weighted_pairwise(sp, i0, wt, n2) + weighted_pairwise(sp, i0 + n2, wt + n2, n - n2);
    }
    sort_upto(sp, i0 + n);
    const rec_t *r = sp->s->sorted + i0;
    if (n < 8) {
        long double res = 0.0L;
        for (size_t i = 0; i < n; i++) {
            res += (long double)wt[i] * term_value(r + i);
        }
        return res;
    }
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
    } else if (n > UINT32_MAX) {
        error = "the image must have fewer than 2^32 pixels";
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
        scratch_t *s = scratch_take(n);
        spread_t sp;
        if (s == NULL || spread_terms((const uint16_t *)gray.buf, (const double *)jlut.buf, h, w, s, &sp) != 0) {
            failed = 1;
        } else {
            sort_upto(&sp, n);
            long double *o = (long double *)out.buf;
            for (size_t i = 0; i < n; i++) {
                o[i] = term_value(s->sorted + i);
            }
        }
        if (s != NULL) {
            scratch_give(s);
        }
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
    } else if (n > UINT32_MAX) {
        error = "the image must have fewer than 2^32 pixels";
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
        scratch_t *s = scratch_take(n);
        spread_t sp;
        if (s == NULL || spread_terms((const uint16_t *)gray.buf, (const double *)jlut.buf, h, w, s, &sp) != 0) {
            failed = 1;
        } else {
            *(long double *)out.buf = 0.0L + weighted_pairwise(&sp, 0, (const float *)weights.buf, n);
        }
        if (s != NULL) {
            scratch_give(s);
        }
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
