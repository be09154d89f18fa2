/* Keeps the blocks CPython's arena allocator frees (object-allocator arenas, 1 MiB; frame data-stack chunks, 16 KiB
 * and up) for reuse instead of unmapping them.
 *
 * CPython maps each such block with mmap and unmaps it as soon as it is free: a thread whose call depth crosses a
 * data-stack chunk boundary again and again (module-level loops of an import made deep in a call stack, e.g. scipy's
 * on a method's first step) maps, faults in and unmaps a fresh 16 KiB chunk at every crossing, thousands of times
 * per process. install() puts a caching allocator in front of the previous one (PyObject_SetArenaAllocator): freed
 * blocks are kept (PER_SIZE_MAX of each size, CACHED_BYTES_MAX in all) and handed out again for the same size;
 * anything else goes to the previous allocator, which also frees what the cache does not keep. Process-wide; called
 * once by ae/memory.py.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <pthread.h>
#include <stddef.h>

/* Freed blocks kept at most: of one size, in all, and bytes in all. */
#define PER_SIZE_MAX 4
#define CACHED_MAX 32
#define CACHED_BYTES_MAX ((size_t)16 << 20)

typedef struct {
    void *ptr;
    size_t size;
} block_t;

static PyObjectArenaAllocator previous;
static int installed;
/* CPython calls the arena allocator with the GIL held; the lock keeps the cache consistent without relying on that. */
static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static block_t cached[CACHED_MAX];
static int n_cached;
static size_t cached_bytes;
static unsigned long long hits, frees_kept;

static void *cache_alloc(void *ctx, size_t size)
{
    (void)ctx;
    pthread_mutex_lock(&lock);
    for (int i = n_cached - 1; i >= 0; i--) {
        if (cached[i].size == size) {
            void *p = cached[i].ptr;
            cached[i] = cached[--n_cached];
            cached_bytes -= size;
            hits++;
            pthread_mutex_unlock(&lock);
            return p;
        }
    }
    pthread_mutex_unlock(&lock);
    return previous.alloc(previous.ctx, size);
}

static void cache_free(void *ctx, void *ptr, size_t size)
{
    (void)ctx;
    if (ptr == NULL) {
        return;
    }
    pthread_mutex_lock(&lock);
    int same = 0;
    for (int i = 0; i < n_cached; i++) {
        same += cached[i].size == size;
    }
    if (same < PER_SIZE_MAX && n_cached < CACHED_MAX && size <= CACHED_BYTES_MAX - cached_bytes) {
        cached[n_cached].ptr = ptr;
        cached[n_cached].size = size;
        n_cached++;
        cached_bytes += size;
        frees_kept++;
        pthread_mutex_unlock(&lock);
        return;
    }
    pthread_mutex_unlock(&lock);
    previous.free(previous.ctx, ptr, size);
}

static PyObject *install(PyObject *self, PyObject *args)
{
    (void)self;
    (void)args;
    if (!installed) {
        PyObject_GetArenaAllocator(&previous);
        PyObjectArenaAllocator mine = {NULL, cache_alloc, cache_free};
        PyObject_SetArenaAllocator(&mine);
        installed = 1;
    }
    Py_RETURN_NONE;
}

static PyObject *stats(PyObject *self, PyObject *args)
{
    (void)self;
    (void)args;
    pthread_mutex_lock(&lock);
    unsigned long long h = hits, k = frees_kept;
    int n = n_cached;
    size_t b = cached_bytes;
    pthread_mutex_unlock(&lock);
    return Py_BuildValue("{s:O,s:K,s:K,s:i,s:n}", "installed", installed ? Py_True : Py_False, "reused", h, "kept",
                         k, "cached_blocks", n, "cached_bytes", (Py_ssize_t)b);
}

static PyMethodDef methods[] = {
    {"install", install, METH_NOARGS,
     "install()\n--\n\nPut the caching arena allocator in front of the current one (once per process)."},
    {"stats", stats, METH_NOARGS,
     "stats()\n--\n\n{installed, reused (blocks handed out again), kept (frees kept), cached_blocks, cached_bytes}."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_arena_cache", NULL, -1, methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__arena_cache(void)
{
    return PyModule_Create(&module);
}
