/*
 * _lut12: the emulation kernel's gather, built with the package (a CPython extension, see pyproject.toml and
 * setup.py): dst[i] = lut[src[i] & 4095] for uint16 buffers, with the GIL released. numpy's take first widens the
 * uint16 codes to 64-bit indices, which costs 2-3x; this loop reads them as they are. code_counts: the pixels at or
 * above a code and at 0 in one pass (the brackets' saturated fractions; numpy needs two comparisons with
 * full-size temporaries and two counts).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <stddef.h>
#include <stdint.h>

#define N_CODES 4096

static void lut12(const uint16_t *lut, const uint16_t *src, uint16_t *dst, size_t n)
{
    size_t i = 0;
    for (; i + 4 <= n; i += 4) {
        uint16_t a = src[i], b = src[i + 1], c = src[i + 2], d = src[i + 3];
        dst[i] = lut[a & 4095u];
        dst[i + 1] = lut[b & 4095u];
        dst[i + 2] = lut[c & 4095u];
        dst[i + 3] = lut[d & 4095u];
    }
    for (; i < n; i++) {
        dst[i] = lut[src[i] & 4095u];
    }
}

static PyObject *gather(PyObject *self, PyObject *args)
{
    Py_buffer lut, src, dst;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*w*", &lut, &src, &dst)) {
        return NULL;
    }
    const char *error = NULL;
    if (lut.len != (Py_ssize_t)(N_CODES * sizeof(uint16_t))) {
        error = "lut must hold 4096 uint16 entries";
    } else if (src.len != dst.len || src.len % (Py_ssize_t)sizeof(uint16_t) != 0) {
        error = "src and dst must be uint16 buffers of the same size";
    }
    if (error == NULL) {
        Py_BEGIN_ALLOW_THREADS
        lut12((const uint16_t *)lut.buf, (const uint16_t *)src.buf, (uint16_t *)dst.buf,
              (size_t)src.len / sizeof(uint16_t));
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&lut);
    PyBuffer_Release(&src);
    PyBuffer_Release(&dst);
    if (error != NULL) {
        PyErr_SetString(PyExc_ValueError, error);
        return NULL;
    }
    Py_RETURN_NONE;
}

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__)
/* compiled for AVX2 and for the baseline, chosen at load time (integer counts: the same in both) */
#define MULTIVERSION __attribute__((target_clones("avx2", "default")))
#else
#define MULTIVERSION
#endif

/* counts[0] += pixels >= code, counts[1] += pixels == 0; in blocks whose 16-bit lane sums cannot overflow */
MULTIVERSION
static void count_codes(const uint16_t *src, size_t n, uint16_t code, size_t *counts)
{
    size_t at = 0, zero = 0;
    for (size_t i0 = 0; i0 < n; i0 += 32768) {
        size_t i1 = n - i0 < 32768 ? n : i0 + 32768;
        uint16_t a = 0, z = 0; /* at most 32768 each: fits */
        for (size_t i = i0; i < i1; i++) {
            a += src[i] >= code;
            z += src[i] == 0;
        }
        at += a;
        zero += z;
    }
    counts[0] = at;
    counts[1] = zero;
}

static PyObject *code_counts(PyObject *self, PyObject *args)
{
    Py_buffer src;
    unsigned int code;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*I", &src, &code)) {
        return NULL;
    }
    if (src.len % (Py_ssize_t)sizeof(uint16_t) != 0 || code > 65535u) {
        PyBuffer_Release(&src);
        PyErr_SetString(PyExc_ValueError, "src must be a uint16 buffer and code a uint16 value");
        return NULL;
    }
    size_t counts[2];
    Py_BEGIN_ALLOW_THREADS
    count_codes((const uint16_t *)src.buf, (size_t)src.len / sizeof(uint16_t), (uint16_t)code, counts);
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&src);
    return Py_BuildValue("nn", (Py_ssize_t)counts[0], (Py_ssize_t)counts[1]);
}

static PyMethodDef methods[] = {
    {"gather", gather, METH_VARARGS,
     "gather(lut, src, dst): dst[i] = lut[src[i] & 4095] for C-contiguous uint16 buffers (lut: 4096 entries)."},
    {"code_counts", code_counts, METH_VARARGS,
     "code_counts(src, code) -> (at_or_above, zero): the pixels of a C-contiguous uint16 buffer at or above code and "
     "at 0."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_lut12", "The emulation kernel's uint16 gather and code counts.", -1,
                                    methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__lut12(void)
{
    return PyModule_Create(&module);
}
