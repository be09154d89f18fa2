/*
 * _lut12: the emulation kernel's gather, built with the package (a CPython extension, see pyproject.toml and
 * setup.py): dst[i] = lut[src[i] & 4095] for uint16 buffers, with the GIL released. numpy's take first widens the
 * uint16 codes to 64-bit indices, which costs 2-3x; this loop reads them as they are.
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

static PyMethodDef methods[] = {
    {"gather", gather, METH_VARARGS,
     "gather(lut, src, dst): dst[i] = lut[src[i] & 4095] for C-contiguous uint16 buffers (lut: 4096 entries)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_lut12", "The emulation kernel's uint16 gather.", -1,
                                    methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__lut12(void)
{
    return PyModule_Create(&module);
}
