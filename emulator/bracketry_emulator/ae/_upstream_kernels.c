/*
 * _upstream_kernels: per-pixel passes of the authors' Shim and Kim metrics (``--parity upstream``, see upstream.py),
 * reduced to what numpy finishes on small tables; upstream.py computes the same values where this was not built.
 *
 * shim_buckets: for a table T[code] (float64: the authors' ((gray - lo) / (hi - lo)) ** gamma of each code), the two
 *   3x3 Sobel gradients with an unsigned 16-bit output exactly as cv2.Sobel(T[gray], CV_16U, ...) computes them on
 *   the float64 image (BORDER_REFLECT_101; row filter then column filter in float64, in OpenCV's order:
 *   x: 2 d(y) + (d(y+1) + d(y-1)) of the row differences d = v(x+1) - v(x-1); y: s(y+1) - s(y-1) of the row sums
 *   s = (v(x-1) + 2 v(x)) + v(x+1); then saturate_cast<ushort>: rounded half to even, negatives and NaN to 0),
 *   stored as one byte per pixel, gx * 6 + gy (the gradients of a [0, 1] image are 0..4; 5 flags "above 4").
 * shim_sum: np.sum(values[codes]) of those bytes and a float32 table, in numpy's pairwise order (float32).
 * kim_code_sums: for the 8-bit image c = gray >> 4, the pixel count of each value and the sum over its pixels of
 *   (gx^2 + gy^2) mod 65536, gx, gy the integer 3x3 Sobel gradients with negatives clipped to 0 (cv2.Sobel on
 *   uint8 with a CV_16U output, BORDER_REFLECT_101), squared and added in uint16 as the authors do.
 *
 * Built with -ffp-contract=off (no fused multiply-add: every float64 operation rounds as OpenCV's do); the hot loops
 * are compiled for AVX2 and the baseline (same IEEE operations). The GIL is released while they run.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__)
/* compiled for AVX2 and for the baseline, chosen at load time (no FMA: the same IEEE operations in both) */
#define MULTIVERSION __attribute__((target_clones("avx2", "default")))
#else
#define MULTIVERSION
#endif

static inline Py_ssize_t refl101(Py_ssize_t i, Py_ssize_t n)
{
    return i < 0 ? -i : (i >= n ? 2 * n - 2 - i : i);
}

/* row r of one gamma: v = table[code], d = v(x+1) - v(x-1), s = (v(x-1) + 2 v(x)) + v(x+1), BORDER_REFLECT_101 */
MULTIVERSION
static void shim_row(const uint16_t *restrict g, const double *restrict table, Py_ssize_t w, double *restrict v,
                     double *restrict d, double *restrict s)
{
    for (Py_ssize_t x = 0; x < w; x++) {
        v[x] = table[g[x]];
    }
    d[0] = v[1] - v[1];
    s[0] = (v[1] + 2.0 * v[0]) + v[1];
    for (Py_ssize_t x = 1; x < w - 1; x++) {
        d[x] = v[x + 1] - v[x - 1];
        double t = v[x - 1] + 2.0 * v[x];
        s[x] = t + v[x + 1];
    }
    d[w - 1] = v[w - 2] - v[w - 2];
    s[w - 1] = (v[w - 2] + 2.0 * v[w - 1]) + v[w - 2];
}

/* The bucket byte gx*6+gy of one pixel's x and y values (each rounded half-even to 0..5 by comparisons: 5 means
   above 4.5); updates the running largest of gx, gy (*top) and the min / max of gx^2 + gy^2 (*lo, *hi). */
static inline uint8_t shim_bucket(double vx, double vy, int *top, int *lo, int *hi)
{
    int gx = (vx > 0.5) + (vx >= 1.5) + (vx > 2.5) + (vx >= 3.5) + (vx > 4.5);
    int gy = (vy > 0.5) + (vy >= 1.5) + (vy > 2.5) + (vy >= 3.5) + (vy > 4.5);
    int q = gx * gx + gy * gy;
    int t = gx > gy ? gx : gy;
    *top = t > *top ? t : *top;
    *lo = q < *lo ? q : *lo;
    *hi = q > *hi ? q : *hi;
    return (uint8_t)(gx * 6 + gy);
}

/* one output row: bucket gx * 6 + gy of every pixel, gx, gy = cv::saturate_cast<ushort> of the column filter
   (round half to even, negatives and NaN -> 0) counted by comparisons up to 5 (5: above 4, out of the table);
   returns the largest gx or gy (5: out of range) in *top and the min / max of gx^2 + gy^2 in m2[0], m2[1] */
MULTIVERSION
static void shim_out_row(const double *restrict du, const double *restrict dm, const double *restrict dd,
                         const double *restrict su, const double *restrict sd, Py_ssize_t n, uint8_t *restrict o,
                         int *top, int *m2)
{
    int tp = *top, lo = m2[0], hi = m2[1];
    for (Py_ssize_t x = 0; x < n; x++) {
        double vx = 2.0 * dm[x] + (dd[x] + du[x]);
        double vy = sd[x] - su[x];
        o[x] = shim_bucket(vx, vy, &tp, &lo, &hi);
    }
    *top = tp;
    m2[0] = lo;
    m2[1] = hi;
}

/* one gamma; returns 0, 1 when a gradient rounds above 4 (the buckets are then incomplete), or -1 when a code is
   outside the table; m2: min and max of gx^2 + gy^2 */
static int shim_image(const uint16_t *g, const double *table, Py_ssize_t n_codes, Py_ssize_t h, Py_ssize_t w,
                      uint8_t *out, double *buf, int *m2)
{
    uint16_t top_code = 0;
    for (Py_ssize_t i = 0; i < h * w; i++) {
        top_code = g[i] > top_code ? g[i] : top_code;
    }
    if (top_code >= n_codes) {
        return -1;
    }
    double *v = buf, *d[3], *s[3];
    Py_ssize_t held[3] = {-1, -1, -1};
    for (int i = 0; i < 3; i++) {
        d[i] = buf + (size_t)(2 * i + 1) * w;
        s[i] = buf + (size_t)(2 * i + 2) * w;
    }
    int top = 0;
    m2[0] = 1 << 30;
    m2[1] = 0;
    for (Py_ssize_t y = 0; y < h; y++) {
        Py_ssize_t rows[3] = {refl101(y - 1, h), y, refl101(y + 1, h)};
        for (int i = 0; i < 3; i++) {
            int slot = (int)(rows[i] % 3);
            if (held[slot] != rows[i]) {
                shim_row(g + rows[i] * w, table, w, v, d[slot], s[slot]);
                held[slot] = rows[i];
            }
        }
        shim_out_row(d[rows[0] % 3], d[rows[1] % 3], d[rows[2] % 3], s[rows[0] % 3], s[rows[2] % 3], w,
                     out + (size_t)y * w, &top, m2);
    }
    return top > 4 ? 1 : 0;
}

/* The argument checks every entry point makes: NULL when ``gray`` is a uint16 HxW buffer of at least 2x2, else the
   message of the ValueError to raise. */
static const char *gray_error(const Py_buffer *gray, Py_ssize_t h, Py_ssize_t w)
{
    if (h < 2 || w < 2) {
        return "the image must be at least 2x2";
    }
    if (gray->len != (Py_ssize_t)((size_t)h * (size_t)w * sizeof(uint16_t))) {
        return "gray must be a C-contiguous uint16 HxW buffer";
    }
    return NULL;
}

/* gray_error, and ``table`` a float64 buffer of at least one value (one per code) */
static const char *shim_inputs_error(const Py_buffer *gray, const Py_buffer *table, Py_ssize_t h, Py_ssize_t w)
{
    const char *error = gray_error(gray, h, w);
    Py_ssize_t n_codes = table->len / (Py_ssize_t)sizeof(double);
    if (error == NULL && (n_codes < 1 || table->len != n_codes * (Py_ssize_t)sizeof(double))) {
        error = "table must be a C-contiguous float64 buffer";
    }
    return error;
}

static PyObject *shim_buckets(PyObject *self, PyObject *args)
{
    Py_buffer gray, table, out;
    Py_ssize_t h, w;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*nnw*", &gray, &table, &h, &w, &out)) {
        return NULL;
    }
    size_t n = (size_t)h * (size_t)w;
    Py_ssize_t n_codes = table.len / (Py_ssize_t)sizeof(double);
    const char *error = shim_inputs_error(&gray, &table, h, w);
    if (error == NULL && out.len != (Py_ssize_t)n) {
        error = "out must be a uint8 HxW buffer";
    }
    int result = 0, failed = 0;
    int m2[2] = {0, 0};
    if (error == NULL) {
        Py_BEGIN_ALLOW_THREADS
        double *buf = (double *)malloc((size_t)7 * w * sizeof(double));
        if (buf == NULL) {
            failed = 1;
        } else {
            result = shim_image((const uint16_t *)gray.buf, (const double *)table.buf, n_codes, h, w,
                                (uint8_t *)out.buf, buf, m2);
            free(buf);
        }
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&gray);
    PyBuffer_Release(&table);
    PyBuffer_Release(&out);
    if (error != NULL) {
        PyErr_SetString(PyExc_ValueError, error);
        return NULL;
    }
    if (failed) {
        return PyErr_NoMemory();
    }
    return Py_BuildValue("iii", result, m2[0], m2[1]);
}

/* The pixels whose gradients can be non-zero for some gamma: a gradient rounds above 0 only when it exceeds 0.5,
   and each is a sum of differences of table values with weights adding to 4 (x: 2 d(y) + (d(y+1) + d(y-1)),
   d = v(x+1) - v(x-1); y: s(y+1) - s(y-1), s a 1-2-1 sum), so one of those differences must reach 1/8. The tables
   rise with the code: v(a) - v(b) >= 1/8 - margin needs a >= partner[b] (partner: the smallest such code over every
   gamma, computed by the caller). A pixel is a candidate when one of its three row pairs (codes at x + 1 and x - 1
   of rows y - 1, y, y + 1) or column pairs (codes at y + 1 and y - 1 of columns x - 1, x, x + 1) passes; BORDER_
   REFLECT_101 as the gradients. Writes the candidates' flat indices, returns their count (-1: a code outside
   partner). rows4: scratch of 4 * w bytes. */
static Py_ssize_t shim_candidates_image(const uint16_t *g, const int32_t *partner, Py_ssize_t n_codes, Py_ssize_t h,
                                        Py_ssize_t w, int32_t *idx, uint8_t *rows4)
{
    for (Py_ssize_t i = 0; i < h * w; i++) {
        if (g[i] >= n_codes) {
            return -1;
        }
    }
    /* hp[r % 3][x]: the row pair of image row r passes at x; vp[x]: the column pair at (y, x) passes */
    uint8_t *hp[3] = {rows4, rows4 + w, rows4 + 2 * w}, *vp = rows4 + 3 * w;
    Py_ssize_t held[3] = {-1, -1, -1}, count = 0;
    for (Py_ssize_t y = 0; y < h; y++) {
        Py_ssize_t rows[3] = {refl101(y - 1, h), y, refl101(y + 1, h)};
        for (int i = 0; i < 3; i++) {
            Py_ssize_t r = rows[i];
            uint8_t *o = hp[r % 3];
            if (held[r % 3] != r) {
                const uint16_t *row = g + r * w;
                for (Py_ssize_t x = 0; x < w; x++) {
                    o[x] = row[refl101(x + 1, w)] >= partner[row[refl101(x - 1, w)]];
                }
                held[r % 3] = r;
            }
        }
        const uint16_t *up = g + rows[0] * w, *down = g + rows[2] * w;
        for (Py_ssize_t x = 0; x < w; x++) {
            vp[x] = down[x] >= partner[up[x]];
        }
        const uint8_t *h0 = hp[rows[0] % 3], *h1 = hp[rows[1] % 3], *h2 = hp[rows[2] % 3];
        for (Py_ssize_t x = 0; x < w; x++) {
            if (h0[x] | h1[x] | h2[x] | vp[refl101(x - 1, w)] | vp[x] | vp[refl101(x + 1, w)]) {
                idx[count++] = (int32_t)(y * w + x);
            }
        }
    }
    return count;
}

static PyObject *shim_candidates(PyObject *self, PyObject *args)
{
    Py_buffer gray, partner, idx;
    Py_ssize_t h, w;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*nnw*", &gray, &partner, &h, &w, &idx)) {
        return NULL;
    }
    size_t n = (size_t)h * (size_t)w;
    Py_ssize_t n_codes = partner.len / (Py_ssize_t)sizeof(int32_t);
    const char *error = gray_error(&gray, h, w);
    if (error != NULL) {
        /* raised once the buffers are released */
    } else if (n > INT32_MAX) {
        error = "the image must have fewer than 2^31 pixels";
    } else if (n_codes < 1 || partner.len != n_codes * (Py_ssize_t)sizeof(int32_t)) {
        error = "partner must be a C-contiguous int32 buffer";
    } else if (idx.len != (Py_ssize_t)(n * sizeof(int32_t))) {
        error = "idx must be an int32 buffer of H*W entries";
    }
    Py_ssize_t count = 0;
    int failed = 0;
    if (error == NULL) {
        Py_BEGIN_ALLOW_THREADS
        uint8_t *rows4 = (uint8_t *)malloc((size_t)4 * w);
        if (rows4 == NULL) {
            failed = 1;
        } else {
            count = shim_candidates_image((const uint16_t *)gray.buf, (const int32_t *)partner.buf, n_codes, h, w,
                                          (int32_t *)idx.buf, rows4);
            free(rows4);
        }
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&gray);
    PyBuffer_Release(&partner);
    PyBuffer_Release(&idx);
    if (error != NULL) {
        PyErr_SetString(PyExc_ValueError, error);
        return NULL;
    }
    if (failed) {
        return PyErr_NoMemory();
    }
    return PyLong_FromSsize_t(count);
}

/* shim_image's bucket at the listed pixels only (the other pixels' gradients are 0, their buckets left as they
   are): the same float64 operations per pixel as shim_row and shim_out_row; m2, top over every pixel (the others
   count as gx = gy = 0 when count < h * w). Returns 0, 1 (a gradient above 4) or -1 (a code outside the table). */
static int shim_sparse_image(const uint16_t *g, const double *table, Py_ssize_t n_codes, Py_ssize_t h, Py_ssize_t w,
                             const int32_t *idx, Py_ssize_t count, uint8_t *out, int *m2)
{
    int tp = 0, lo = count < h * w ? 0 : 1 << 30, hi = 0;
    for (Py_ssize_t k = 0; k < count; k++) {
        Py_ssize_t y = idx[k] / w, x = idx[k] % w;
        const uint16_t *ru = g + refl101(y - 1, h) * w, *rm = g + y * w, *rd = g + refl101(y + 1, h) * w;
        Py_ssize_t xm = refl101(x - 1, w), xp = refl101(x + 1, w);
        uint16_t c[8] = {ru[xm], ru[x], ru[xp], rm[xm], rm[xp], rd[xm], rd[x], rd[xp]};
        for (int j = 0; j < 8; j++) {
            if (c[j] >= n_codes) {
                return -1;
            }
        }
        double du = table[c[2]] - table[c[0]], dm = table[c[4]] - table[c[3]], dd = table[c[7]] - table[c[5]];
        double tu = table[c[0]] + 2.0 * table[c[1]], td = table[c[5]] + 2.0 * table[c[6]];
        double su = tu + table[c[2]], sd = td + table[c[7]];
        double vx = 2.0 * dm + (dd + du);
        double vy = sd - su;
        out[idx[k]] = shim_bucket(vx, vy, &tp, &lo, &hi);
    }
    m2[0] = lo;
    m2[1] = hi;
    return tp > 4 ? 1 : 0;
}

static PyObject *shim_sparse(PyObject *self, PyObject *args)
{
    Py_buffer gray, table, idx, out;
    Py_ssize_t h, w, count;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*nny*nw*", &gray, &table, &h, &w, &idx, &count, &out)) {
        return NULL;
    }
    size_t n = (size_t)h * (size_t)w;
    Py_ssize_t n_codes = table.len / (Py_ssize_t)sizeof(double);
    const char *error = shim_inputs_error(&gray, &table, h, w);
    if (error != NULL) {
        /* raised once the buffers are released */
    } else if (count < 0 || (size_t)count > n || idx.len < count * (Py_ssize_t)sizeof(int32_t)) {
        error = "idx must hold count int32 pixel indices";
    } else if (out.len != (Py_ssize_t)n) {
        error = "out must be a uint8 HxW buffer";
    }
    if (error == NULL) { /* indices from shim_candidates; checked here all the same (no write outside out) */
        const int32_t *ix = (const int32_t *)idx.buf;
        for (Py_ssize_t k = 0; k < count; k++) {
            if (ix[k] < 0 || (size_t)ix[k] >= n) {
                error = "idx holds an index outside the image";
                break;
            }
        }
    }
    int result = 0;
    int m2[2] = {0, 0};
    if (error == NULL) {
        Py_BEGIN_ALLOW_THREADS
        result = shim_sparse_image((const uint16_t *)gray.buf, (const double *)table.buf, n_codes, h, w,
                                   (const int32_t *)idx.buf, count, (uint8_t *)out.buf, m2);
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&gray);
    PyBuffer_Release(&table);
    PyBuffer_Release(&idx);
    PyBuffer_Release(&out);
    if (error != NULL) {
        PyErr_SetString(PyExc_ValueError, error);
        return NULL;
    }
    return Py_BuildValue("iii", result, m2[0], m2[1]);
}

/* numpy's pairwise sum (float32 accumulators: blocks of at most 128 summed by 8 accumulators, halves at multiples
   of 8) of values[b[i]], i < n; a block of zero codes adds nothing when values[0] is +0 */
static float pairwise_sum(const uint8_t *b, Py_ssize_t n, const float *values, int zero0)
{
    if (n < 8) {
        float res = 0.0f;
        for (Py_ssize_t i = 0; i < n; i++) {
            res += values[b[i]];
        }
        return res;
    }
    if (n <= 128) {
        if (zero0) {
            uint64_t any = 0;
            Py_ssize_t i = 0;
            for (; i + 8 <= n; i += 8) {
                uint64_t word;
                memcpy(&word, b + i, 8);
                any |= word;
            }
            for (; i < n; i++) {
                any |= b[i];
            }
            if (any == 0) {
                return 0.0f;
            }
        }
        float r[8];
        for (int j = 0; j < 8; j++) {
            r[j] = values[b[j]];
        }
        Py_ssize_t i = 8;
        for (; i < n - (n % 8); i += 8) {
            for (int j = 0; j < 8; j++) {
                r[j] += values[b[i + j]];
            }
        }
        float res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
        for (; i < n; i++) {
            res += values[b[i]];
        }
        return res;
    }
    Py_ssize_t n2 = n / 2;
    n2 -= n2 % 8;
    return pairwise_sum(b, n2, values, zero0) + pairwise_sum(b + n2, n - n2, values, zero0);
}

static PyObject *shim_sum(PyObject *self, PyObject *args)
{
    Py_buffer codes, values;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*", &codes, &values)) {
        return NULL;
    }
    if (values.len != (Py_ssize_t)(256 * sizeof(float))) {
        PyBuffer_Release(&codes);
        PyBuffer_Release(&values);
        PyErr_SetString(PyExc_ValueError, "values must be float32 (256,)");
        return NULL;
    }
    const float *v = (const float *)values.buf;
    uint32_t bits0;
    memcpy(&bits0, v, sizeof bits0);
    float res;
    Py_BEGIN_ALLOW_THREADS
    res = pairwise_sum((const uint8_t *)codes.buf, codes.len, v, bits0 == 0);
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&codes);
    PyBuffer_Release(&values);
    return PyFloat_FromDouble((double)res);
}

/* returns 0, or -1 when a pixel is above 4095 */
static int kim_image(const uint16_t *g, Py_ssize_t h, Py_ssize_t w, int64_t *counts, int64_t *gsum, int32_t *rows3)
{
    int32_t *c[3];
    Py_ssize_t held[3] = {-1, -1, -1};
    for (int i = 0; i < 3; i++) {
        c[i] = rows3 + (size_t)i * w;
    }
    for (Py_ssize_t y = 0; y < h; y++) {
        Py_ssize_t rows[3] = {refl101(y - 1, h), y, refl101(y + 1, h)};
        for (int i = 0; i < 3; i++) {
            int slot = (int)(rows[i] % 3);
            if (held[slot] != rows[i]) {
                const uint16_t *src = g + rows[i] * w;
                int32_t *dst = c[slot];
                uint16_t hi = 0;
                for (Py_ssize_t x = 0; x < w; x++) {
                    hi |= src[x];
                    dst[x] = src[x] >> 4;
                }
                if (hi > 4095) {
                    return -1;
                }
                held[slot] = rows[i];
            }
        }
        const int32_t *u = c[rows[0] % 3], *m = c[rows[1] % 3], *d = c[rows[2] % 3];
        for (Py_ssize_t x = 0; x < w; x++) {
            Py_ssize_t xm = refl101(x - 1, w), xp = refl101(x + 1, w);
            int32_t gx = (u[xp] + 2 * m[xp] + d[xp]) - (u[xm] + 2 * m[xm] + d[xm]);
            int32_t gy = (d[xm] + 2 * d[x] + d[xp]) - (u[xm] + 2 * u[x] + u[xp]);
            gx = gx > 0 ? gx : 0;
            gy = gy > 0 ? gy : 0;
            uint32_t g2 = ((uint32_t)(gx * gx) + (uint32_t)(gy * gy)) & 0xFFFFu;
            counts[m[x]] += 1;
            gsum[m[x]] += g2;
        }
    }
    return 0;
}

static PyObject *kim_code_sums(PyObject *self, PyObject *args)
{
    Py_buffer gray, counts, gsum;
    Py_ssize_t h, w;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*nnw*w*", &gray, &h, &w, &counts, &gsum)) {
        return NULL;
    }
    const char *error = gray_error(&gray, h, w);
    Py_ssize_t sums_len = (Py_ssize_t)(256 * sizeof(int64_t));
    if (error == NULL && (counts.len != sums_len || gsum.len != sums_len)) {
        error = "counts and sums must be int64 (256,) buffers";
    }
    int result = 0;
    int failed = 0;
    if (error == NULL) {
        Py_BEGIN_ALLOW_THREADS
        int32_t *rows3 = (int32_t *)malloc((size_t)3 * w * sizeof(int32_t));
        if (rows3 == NULL) {
            failed = 1;
        } else {
            memset(counts.buf, 0, 256 * sizeof(int64_t));
            memset(gsum.buf, 0, 256 * sizeof(int64_t));
            result = kim_image((const uint16_t *)gray.buf, h, w, (int64_t *)counts.buf, (int64_t *)gsum.buf, rows3);
            free(rows3);
        }
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&gray);
    PyBuffer_Release(&counts);
    PyBuffer_Release(&gsum);
    if (error != NULL) {
        PyErr_SetString(PyExc_ValueError, error);
        return NULL;
    }
    if (failed) {
        return PyErr_NoMemory();
    }
    return PyLong_FromLong(result);
}

static PyMethodDef methods[] = {
    {"shim_buckets", shim_buckets, METH_VARARGS,
     "shim_buckets(gray, table, h, w, out) -> (status, min, max): the authors' CV_16U Sobel gradients of table[gray], "
     "gx * 6 + gy into out (uint8 HxW); status 0, 1 when a gradient is above 4 (out incomplete), -1 when a code is "
     "outside the table; min, max of gx^2 + gy^2; gray: C-contiguous uint16 HxW codes, table: float64 (codes,)."},
    {"shim_candidates", shim_candidates, METH_VARARGS,
     "shim_candidates(gray, partner, h, w, idx) -> count: the flat indices (into idx, int32 H*W) of the pixels whose "
     "Shim gradients can be non-zero for a table where v(a) - v(b) reaches 1/8 only for a >= partner[b] (int32 "
     "(codes,)); -1 when a code is outside partner."},
    {"shim_sparse", shim_sparse, METH_VARARGS,
     "shim_sparse(gray, table, h, w, idx, count, out) -> (status, min, max): shim_buckets at the count listed pixels "
     "only (the others' gradients must be 0; their bytes in out are left as they are); min, max over every pixel."},
    {"shim_sum", shim_sum, METH_VARARGS,
     "shim_sum(codes, values) -> float: np.sum(values[codes]) of a uint8 buffer and float32 (256,) values, bit for "
     "bit (numpy's pairwise float32 summation)."},
    {"kim_code_sums", kim_code_sums, METH_VARARGS,
     "kim_code_sums(gray, h, w, counts, sums) -> 0 (-1: a code above 4095): per 8-bit code (gray >> 4) the pixel "
     "count and the sum of (gx^2 + gy^2) mod 65536 of the clipped integer Sobel gradients; counts, sums: int64 "
     "(256,)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_upstream_kernels",
                                    "Per-pixel passes of the authors' Shim and Kim metrics.", -1, methods, NULL, NULL,
                                    NULL, NULL};

PyMODINIT_FUNC PyInit__upstream_kernels(void)
{
    return PyModule_Create(&module);
}
