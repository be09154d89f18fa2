/*
 * _kernels: the hot loops of the synthetic world's frames, bit for bit what the numpy paths compute (those stay the
 * fallback when this extension is not built, or with BRACKETRY_NO_CKERNEL=1).
 *
 * nearest_trunks -- the nearest tree-trunk hit of every pixel for the ray caster (SideRenderer._cylinders in
 * render.py), without materialising the (pixel, piece) pairs. For each trunk piece's screen rectangle, in the order given, and each pixel of it, row by row: the float32 ray /
 * vertical-cylinder intersection of render.py (same operations in the same order, each rounded to float32):
 *
 *   a = max(dx*dx + dy*dy, 1e-12); b = ocx*dx + ocy*dy; disc = b*b - a*c; t = -((sqrt(max(disc, 0)) + b) / a)
 *   z = t*dz + oz; hit when disc > 0, t > 0, z0 <= z < z1
 *
 * and the pixel keeps the hit with the smallest t, the later piece on a tie (numpy assigns the shading of every
 * tied piece in pair order, so the last one shows).
 *
 * shade_trunks -- the bark shading of the trunk hits that show (SideRenderer._shade_cylinders).
 *
 * expose_gaussian -- a noisy exposure from pre-drawn standard normals (CameraModel.expose with ``normal``):
 *   mean = min(rate * t_us, 2 full well); e = normal * sqrt(mean + read_var) + mean; level = clip(e * inv_gain +
 *   offset, 0, 4095) truncated; code = lut[level].
 *
 * Built with -ffp-contract=off (no fused multiply-add: every float32 product and sum rounds as numpy's do).
 * The GIL is released while it runs.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

static void nearest(const float *dx, const float *dy, const float *dz, Py_ssize_t w, const int64_t *rects,
                    const int64_t *piece, Py_ssize_t m, const float *ocx, const float *ocy, const float *cc,
                    const float *z0, const float *z1, float oz, float *best_t, int32_t *best_piece)
{
    for (Py_ssize_t i = 0; i < m; i++) {
        const int64_t *r = rects + 4 * i;
        const int64_t k = piece[i];
        const float px = ocx[k], py = ocy[k], c = cc[k], lo = z0[k], hi = z1[k];
        for (int64_t row = r[0]; row < r[1]; row++) {
            const Py_ssize_t base = (Py_ssize_t)row * w;
            for (int64_t col = r[2]; col < r[3]; col++) {
                const Py_ssize_t p = base + (Py_ssize_t)col;
                const float ex = dx[p], ey = dy[p];
                float a = ex * ex;
                a = a + ey * ey;
                if (!(a >= 1e-12f)) { /* np.maximum(a, 1e-12) (a is never NaN here) */
                    a = 1e-12f;
                }
                float b = px * ex;
                b = b + py * ey;
                float disc = b * b;
                disc = disc - a * c;
                if (!(disc > 0.0f)) {
                    continue;
                }
                float t = sqrtf(disc);
                t = t + b;
                t = t / a;
                t = -t;
                if (!(t > 0.0f)) {
                    continue;
                }
                float z = t * dz[p];
                z = z + oz;
                if (z >= lo && z < hi && t <= best_t[p]) {
                    best_t[p] = t;
                    best_piece[p] = (int32_t)k;
                }
            }
        }
    }
}

static PyObject *nearest_trunks(PyObject *self, PyObject *args)
{
    Py_buffer dx, dy, dz, rects, piece, ocx, ocy, cc, z0, z1, best_t, best_piece;
    Py_ssize_t w;
    float oz;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*y*ny*y*y*y*y*y*y*fw*w*", &dx, &dy, &dz, &w, &rects, &piece, &ocx, &ocy, &cc,
                          &z0, &z1, &oz, &best_t, &best_piece)) {
        return NULL;
    }
    const char *error = NULL;
    const Py_ssize_t n = dx.len / (Py_ssize_t)sizeof(float);
    const Py_ssize_t m = piece.len / (Py_ssize_t)sizeof(int64_t);
    const Py_ssize_t n_pieces = ocx.len / (Py_ssize_t)sizeof(float);
    if (w < 1 || n % w != 0 || dy.len != dx.len || dz.len != dx.len) {
        error = "dx, dy, dz must be float32 buffers of H*W values";
    } else if (best_t.len != dx.len || best_piece.len != n * (Py_ssize_t)sizeof(int32_t)) {
        error = "best_t (float32) and best_piece (int32) must hold H*W values";
    } else if (rects.len != 4 * piece.len) {
        error = "rects must be int64 (M, 4) for M int64 piece indices";
    } else if (ocy.len != ocx.len || cc.len != ocx.len || z0.len != ocx.len || z1.len != ocx.len) {
        error = "ocx, ocy, c, z0, z1 must be float32 buffers of one value per piece";
    } else {
        const int64_t *r = (const int64_t *)rects.buf;
        const int64_t *k = (const int64_t *)piece.buf;
        const Py_ssize_t h = n / w;
        for (Py_ssize_t i = 0; i < m && error == NULL; i++) {
            if (k[i] < 0 || k[i] >= n_pieces) {
                error = "piece index out of range";
            } else if (r[4 * i] < 0 || r[4 * i + 1] > h || r[4 * i + 2] < 0 || r[4 * i + 3] > w) {
                error = "rectangle outside the image";
            }
        }
    }
    if (error == NULL) {
        Py_BEGIN_ALLOW_THREADS
        nearest((const float *)dx.buf, (const float *)dy.buf, (const float *)dz.buf, w, (const int64_t *)rects.buf,
                (const int64_t *)piece.buf, m, (const float *)ocx.buf, (const float *)ocy.buf, (const float *)cc.buf,
                (const float *)z0.buf, (const float *)z1.buf, oz, (float *)best_t.buf, (int32_t *)best_piece.buf);
        Py_END_ALLOW_THREADS
    }
    Py_buffer *all[] = {&dx, &dy, &dz, &rects, &piece, &ocx, &ocy, &cc, &z0, &z1, &best_t, &best_piece};
    for (size_t i = 0; i < sizeof all / sizeof all[0]; i++) {
        PyBuffer_Release(all[i]);
    }
    if (error != NULL) {
        PyErr_SetString(PyExc_ValueError, error);
        return NULL;
    }
    Py_RETURN_NONE;
}

/* render.py's pseudo_angle: float32 in [0, 4), monotonic in the angle of (x, y) */
static inline float pseudo_angle(float x, float y)
{
    float den = fabsf(x) + fabsf(y);
    den = den + 1e-20f;
    const float p = y / den;
    float q = x >= 0.0f ? p : 2.0f - p;
    if (q < 0.0f) {
        q = q + 4.0f;
    }
    return q;
}

/* numpy's remainder of float64 by a positive divisor (the sign of the divisor) */
static inline double floor_mod(double a, double b)
{
    double m = fmod(a, b);
    if (m != 0.0) {
        if (m < 0.0) {
            m += b;
        }
    } else {
        m = copysign(0.0, b);
    }
    return m;
}

static inline int64_t int_floor_mod(int64_t a, int64_t b)
{
    int64_t m = a % b;
    return (m != 0 && ((m < 0) != (b < 0))) ? m + b : m;
}

typedef struct {
    const int32_t *pix;
    const int64_t *piece, *parent;
    const float *t, *dx, *dy, *dz, *px, *py, *pr, *bark, *albedo, *sun_map, *sky_map;
    const int32_t *kind;
    const int8_t *chan;
    float ox, oy, oz, sun0, sun1;
    int64_t nu, nv;
} shade_args;

static void shade(const shade_args *a, Py_ssize_t k_n, float *out)
{
    const float scale_u = (float)((double)a->nu / 4.0);
    for (Py_ssize_t i = 0; i < k_n; i++) {
        const Py_ssize_t p = a->pix[i];
        const int64_t k = a->piece[i];
        const int64_t ob = a->parent[k];
        const float t = a->t[i], r = a->pr[k];
        float nx = a->ox - a->px[k];
        nx = nx + t * a->dx[p];
        nx = nx / r;
        float ny = a->oy - a->py[k];
        ny = ny + t * a->dy[p];
        ny = ny / r;
        float z = t * a->dz[p];
        z = a->oz + z;
        int32_t u = (int32_t)(pseudo_angle(nx, ny) * scale_u);
        if (u > a->nu - 1) {
            u = (int32_t)(a->nu - 1);
        } else if (u < 0) { /* only a NaN normal (never for a hit): keep the lookup inside the texture */
            u = 0;
        }
        int64_t v = (int64_t)(int32_t)(z * 4.0f);
        v = (int32_t)(v + int_floor_mod(ob * 37, a->nv));
        v = int_floor_mod(v, a->nv);
        v = (int32_t)(v * a->nu);
        v = (int32_t)(v + u);
        float tex = a->bark[v];
        if (a->kind[ob] == 1) {
            const double w = (double)(z * 3.1f) + (double)ob * (double)0.37f;
            if (floor_mod(w, (double)1.0f) < 0.12 && int_floor_mod((int64_t)(u >> 4) + ob, 3) != 0) {
                tex = 0.15f;
            }
        }
        tex = tex * a->albedo[ob * 3 + a->chan[p]];
        float light = nx * a->sun0;
        light = light + ny * a->sun1;
        if (!(light >= 0.0f)) { /* np.maximum(light, 0) (light is never NaN here) */
            light = 0.0f;
        }
        light = light * a->sun_map[p];
        light = light + 0.5f * a->sky_map[p];
        out[i] = tex * light;
    }
}

static PyObject *shade_trunks(PyObject *self, PyObject *args)
{
    Py_buffer b[16];
    shade_args a;
    Py_buffer out;
    (void)self;
    memset(b, 0, sizeof b);
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*y*y*y*y*y*y*y*y*y*y*fffffLLw*", &b[0], &b[1], &b[2], &b[3], &b[4], &b[5],
                          &b[6], &b[7], &b[8], &b[9], &b[10], &b[11], &b[12], &b[13], &b[14], &b[15],
                          &a.ox, &a.oy, &a.oz, &a.sun0, &a.sun1, &a.nu, &a.nv, &out)) {
        return NULL;
    }
    const char *error = NULL;
    const Py_ssize_t k_n = b[0].len / (Py_ssize_t)sizeof(int32_t);
    const Py_ssize_t n = b[3].len / (Py_ssize_t)sizeof(float);
    const Py_ssize_t n_pieces = b[6].len / (Py_ssize_t)sizeof(float);
    const Py_ssize_t n_trunks = b[11].len / (Py_ssize_t)sizeof(int32_t);
    a.pix = (const int32_t *)b[0].buf;
    a.piece = (const int64_t *)b[1].buf;
    a.t = (const float *)b[2].buf;
    a.dx = (const float *)b[3].buf;
    a.dy = (const float *)b[4].buf;
    a.dz = (const float *)b[5].buf;
    a.px = (const float *)b[6].buf;
    a.py = (const float *)b[7].buf;
    a.pr = (const float *)b[8].buf;
    a.parent = (const int64_t *)b[9].buf;
    a.chan = (const int8_t *)b[10].buf;
    a.kind = (const int32_t *)b[11].buf;
    a.bark = (const float *)b[12].buf;
    a.albedo = (const float *)b[13].buf;
    a.sun_map = (const float *)b[14].buf;
    a.sky_map = (const float *)b[15].buf;
    if (b[1].len != k_n * (Py_ssize_t)sizeof(int64_t) || b[2].len != k_n * (Py_ssize_t)sizeof(float)
        || out.len != k_n * (Py_ssize_t)sizeof(float)) {
        error = "pix (int32), piece (int64), t and out (float32) must have one value per hit";
    } else if (b[4].len != b[3].len || b[5].len != b[3].len || b[10].len != n || b[14].len != b[3].len
               || b[15].len != b[3].len) {
        error = "dx, dy, dz, sun_map, sky_map (float32) and chan (int8) must have one value per pixel";
    } else if (b[7].len != b[6].len || b[8].len != b[6].len || b[9].len != n_pieces * (Py_ssize_t)sizeof(int64_t)) {
        error = "px, py, r (float32) and parent (int64) must have one value per piece";
    } else if (a.nu < 1 || a.nv < 1 || b[12].len != a.nu * a.nv * (int64_t)sizeof(float)
               || b[13].len != 3 * n_trunks * (Py_ssize_t)sizeof(float)) {
        error = "bark must be float32 nv*nu, albedo float32 (trunks, 3), kind int32 (trunks,)";
    } else {
        for (Py_ssize_t i = 0; i < k_n && error == NULL; i++) {
            if (a.pix[i] < 0 || a.pix[i] >= n || a.piece[i] < 0 || a.piece[i] >= n_pieces
                || a.parent[a.piece[i]] < 0 || a.parent[a.piece[i]] >= n_trunks || a.chan[a.pix[i]] < 0
                || a.chan[a.pix[i]] > 2) {
                error = "hit outside the image, the pieces or the trunks";
            }
        }
    }
    if (error == NULL) {
        Py_BEGIN_ALLOW_THREADS
        shade(&a, k_n, (float *)out.buf);
        Py_END_ALLOW_THREADS
    }
    for (size_t i = 0; i < sizeof b / sizeof b[0]; i++) {
        PyBuffer_Release(&b[i]);
    }
    PyBuffer_Release(&out);
    if (error != NULL) {
        PyErr_SetString(PyExc_ValueError, error);
        return NULL;
    }
    Py_RETURN_NONE;
}

static PyObject *expose_gaussian(PyObject *self, PyObject *args)
{
    Py_buffer rate, normal, lut, out;
    float t_us, max_e, read_var, inv_gain, offset;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*fffffy*w*", &rate, &normal, &t_us, &max_e, &read_var, &inv_gain, &offset, &lut,
                          &out)) {
        return NULL;
    }
    const char *error = NULL;
    const Py_ssize_t n = rate.len / (Py_ssize_t)sizeof(float);
    if (normal.len != rate.len || out.len != n * (Py_ssize_t)sizeof(uint16_t)) {
        error = "rate, normal (float32) and out (uint16) must have one value per pixel";
    } else if (lut.len != 4096 * (Py_ssize_t)sizeof(uint16_t)) {
        error = "lut must hold 4096 uint16 codes";
    }
    if (error == NULL) {
        const float *r = (const float *)rate.buf, *g = (const float *)normal.buf;
        const uint16_t *l = (const uint16_t *)lut.buf;
        uint16_t *o = (uint16_t *)out.buf;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t i = 0; i < n; i++) {
            /* NaN never comes here (rates are finite); numpy's clip would keep it and its cast is undefined */
            float mean = r[i] * t_us;
            mean = mean < max_e ? mean : max_e;
            float e = g[i] * sqrtf(mean + read_var);
            e = e + mean;
            e = e * inv_gain;
            e = e + offset;
            e = e > 0.0f ? e : 0.0f;
            e = e < 4095.0f ? e : 4095.0f;
            o[i] = l[(int32_t)e];
        }
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&rate);
    PyBuffer_Release(&normal);
    PyBuffer_Release(&lut);
    PyBuffer_Release(&out);
    if (error != NULL) {
        PyErr_SetString(PyExc_ValueError, error);
        return NULL;
    }
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"nearest_trunks", nearest_trunks, METH_VARARGS,
     "nearest_trunks(dx, dy, dz, w, rects, piece, ocx, ocy, c, z0, z1, oz, best_t, best_piece): for every pixel of "
     "every rectangle (int64 (M, 4): r0, r1, c0, c1) of trunk piece piece[i] (int64 (M,)), the ray's hit on that "
     "piece; a hit nearer than (or as near as) best_t[p] (float32, H*W) replaces it and its piece in best_piece[p] "
     "(int32, H*W). dx, dy, dz: float32 H*W world ray directions; ocx, ocy, c, z0, z1: float32 per piece; oz: the "
     "camera height."},
    {"shade_trunks", shade_trunks, METH_VARARGS,
     "shade_trunks(pix, piece, t, dx, dy, dz, px, py, r, parent, chan, kind, bark, albedo, sun_map, sky_map, "
     "ox, oy, oz, sun_x, sun_y, nu, nv, out): the radiance of each trunk hit (render.py's _shade_cylinders) into out "
     "(float32, one per hit)."},
    {"expose_gaussian", expose_gaussian, METH_VARARGS,
     "expose_gaussian(rate, normal, t_us, max_e, read_var, inv_gain, offset, lut, out): the codes of a noisy exposure "
     "(camera_model.py's expose with pre-drawn normals) into out (uint16, one per pixel)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_kernels", "Hot loops of the synthetic world's frames.", -1,
                                    methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__kernels(void)
{
    return PyModule_Create(&module);
}
