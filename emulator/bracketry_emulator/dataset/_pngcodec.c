/*
 * _pngcodec: a decoder for the PNGs the brackets are stored in (gray, 8 or 16 bits a sample, not interlaced) and an
 * encoder of the emulator's ``stored`` PNGs, built with the package (see pyproject.toml) and linked with libdeflate.
 * imageio.py calls the decoder and falls back to OpenCV for everything else; emulation/writer.py calls the encoder
 * and falls back to Python's zlib (same bytes).
 *
 * decode(path, out) reads the whole file, checks every chunk's CRC, inflates the concatenated IDAT data in one call
 * (libdeflate, which also checks the zlib Adler-32), undoes the five row filters and writes the samples in native
 * byte order straight into ``out`` (a writable C-contiguous buffer of exactly height x width samples), or into a
 * new bytearray when ``out`` is None. The GIL is released while it works.
 *
 * It only succeeds on a file that is valid in every respect it looks at; for anything else (another colour type or
 * depth, interlacing, a bad CRC or checksum, a truncated or malformed file, not a PNG at all) it returns None and
 * decides nothing, so that the caller's fallback (OpenCV) gives the same image, or the same failure, as before.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <errno.h>
#include <fcntl.h>
#include <libdeflate.h>
#include <pthread.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#ifndef MADV_POPULATE_WRITE
#define MADV_POPULATE_WRITE 23 /* Linux >= 5.14 */
#endif

#ifdef __SSE2__
#include <emmintrin.h>
#endif

/* Per-thread scratch buffers (the file and the inflated rows), kept between calls: no fresh pages per frame. */
typedef struct {
    uint8_t *file;
    size_t file_cap;
    uint8_t *raw;
    size_t raw_cap;
    uint8_t *member; /* a deflated zip member as read, before inflating */
    size_t member_cap;
    struct libdeflate_decompressor *inflater;
} scratch_t;

static pthread_key_t scratch_key;

static void scratch_free(void *p)
{
    scratch_t *s = (scratch_t *)p;
    if (s == NULL) {
        return;
    }
    free(s->file);
    free(s->raw);
    free(s->member);
    if (s->inflater != NULL) {
        libdeflate_free_decompressor(s->inflater);
    }
    free(s);
}

static scratch_t *scratch_get(void)
{
    scratch_t *s = (scratch_t *)pthread_getspecific(scratch_key);
    if (s == NULL) {
        s = (scratch_t *)calloc(1, sizeof(scratch_t));
        if (s == NULL) {
            return NULL;
        }
        s->inflater = libdeflate_alloc_decompressor();
        if (s->inflater == NULL || pthread_setspecific(scratch_key, s) != 0) {
            scratch_free(s);
            return NULL;
        }
    }
    return s;
}

/* Grows a scratch buffer to at least n bytes, with headroom (a quarter more, in whole MiB): the files of one run differ
   in size by tens of percent, and every regrowth is a fresh block whose pages fault in again. */
static int reserve(uint8_t **buf, size_t *cap, size_t n)
{
    if (*cap >= n) {
        return 0;
    }
    const size_t mib = (size_t)1 << 20;
    size_t want = n + n / 4;
    want = (want < n || want > SIZE_MAX - mib) ? n : (want + mib - 1) / mib * mib;
    uint8_t *p = (uint8_t *)malloc(want);
    if (p == NULL) {
        return -1;
    }
    free(*buf);
    *buf = p;
    *cap = want;
    return 0;
}

static inline uint32_t be32(const uint8_t *p)
{
    return ((uint32_t)p[0] << 24) | ((uint32_t)p[1] << 16) | ((uint32_t)p[2] << 8) | (uint32_t)p[3];
}

/* --- row filters (PNG specification, filter method 0); ``bpp`` bytes a pixel (1 or 2) --- */

static void unfilter_sub(uint8_t *row, size_t n, size_t bpp)
{
    size_t i = bpp;
#ifdef __SSE2__
    if (bpp == 2 && n >= 16) {
        /* prefix sums of each byte lane over the pixels, 8 pixels a vector, carried from vector to vector */
        __m128i carry = _mm_setzero_si128();
        for (i = 0; i + 16 <= n; i += 16) {
            __m128i x = _mm_loadu_si128((const __m128i *)(row + i));
            x = _mm_add_epi8(x, _mm_slli_si128(x, 2));
            x = _mm_add_epi8(x, _mm_slli_si128(x, 4));
            x = _mm_add_epi8(x, _mm_slli_si128(x, 8));
            x = _mm_add_epi8(x, carry);
            _mm_storeu_si128((__m128i *)(row + i), x);
            __m128i last = _mm_shufflehi_epi16(x, _MM_SHUFFLE(3, 3, 3, 3));
            carry = _mm_unpackhi_epi64(last, last);
        }
        if (i == 0) {
            i = bpp;
        }
    }
#endif
    for (; i < n; i++) {
        row[i] = (uint8_t)(row[i] + row[i - bpp]);
    }
}

static void unfilter_up(uint8_t *row, const uint8_t *prior, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        row[i] = (uint8_t)(row[i] + prior[i]);
    }
}

static void unfilter_avg(uint8_t *row, const uint8_t *prior, size_t n, size_t bpp)
{
    for (size_t i = 0; i < bpp && i < n; i++) {
        row[i] = (uint8_t)(row[i] + (prior[i] >> 1));
    }
    for (size_t i = bpp; i < n; i++) {
        row[i] = (uint8_t)(row[i] + (((unsigned)row[i - bpp] + prior[i]) >> 1));
    }
}

static void unfilter_paeth(uint8_t *row, const uint8_t *prior, size_t n, size_t bpp)
{
    for (size_t i = 0; i < bpp && i < n; i++) {
        row[i] = (uint8_t)(row[i] + prior[i]);  /* a = c = 0: the predictor is b */
    }
    for (size_t i = bpp; i < n; i++) {
        int a = row[i - bpp], b = prior[i], c = prior[i - bpp];
        int p = a + b - c;
        int pa = abs(p - a), pb = abs(p - b), pc = abs(p - c);
        int pred = (pa <= pb && pa <= pc) ? a : (pb <= pc ? b : c);
        row[i] = (uint8_t)(row[i] + pred);
    }
}

/* big-endian 16-bit samples -> native uint16; returns the OR of the samples */
static uint32_t swap_row16(const uint8_t *src, uint16_t *dst, size_t w)
{
    uint16_t acc = 0;
    for (size_t j = 0; j < w; j++) {
        uint16_t v;
        memcpy(&v, src + 2 * j, 2);
        v = __builtin_bswap16(v);
        dst[j] = v;
        acc |= v;
    }
    return acc;
}

static uint32_t copy_row8(const uint8_t *src, uint8_t *dst, size_t w)
{
    uint8_t acc = 0;
    for (size_t j = 0; j < w; j++) {
        dst[j] = src[j];
        acc |= src[j];
    }
    return acc;
}

typedef struct {
    uint32_t width, height;
    int depth;
} header_t;

/* Outcome of the work done without the GIL. */
enum { OK = 0, FALLBACK = 1, NO_MEMORY = 2, OS_ERROR = 3 };

static int read_file(const char *path, scratch_t *s, size_t *size, int *err)
{
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd < 0) {
        *err = errno;
        return OS_ERROR;
    }
    struct stat st;
    if (fstat(fd, &st) != 0) {
        *err = errno;
        close(fd);
        return OS_ERROR;
    }
    size_t n = (size_t)st.st_size;
    if (reserve(&s->file, &s->file_cap, n + 1) != 0) {
        close(fd);
        return NO_MEMORY;
    }
    size_t got = 0;
    while (got < n) {
        ssize_t r = read(fd, s->file + got, n - got);
        if (r < 0) {
            if (errno == EINTR) {
                continue;
            }
            *err = errno;
            close(fd);
            return OS_ERROR;
        }
        if (r == 0) {
            break;
        }
        got += (size_t)r;
    }
    close(fd);
    *size = got;
    return OK;
}

static const uint8_t SIGNATURE[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};

/* Checks the chunks and moves the IDAT payloads together at the start of the file buffer. */
static int parse(uint8_t *f, size_t n, header_t *hdr, size_t *idat_len)
{
    if (n < 8 || memcmp(f, SIGNATURE, 8) != 0) {
        return FALLBACK;
    }
    size_t pos = 8, packed = 0;
    int seen_ihdr = 0, seen_iend = 0, idat_state = 0; /* 0 before, 1 inside, 2 after the IDAT run */
    while (!seen_iend) {
        if (n - pos < 12) {
            return FALLBACK;
        }
        uint32_t len = be32(f + pos);
        const uint8_t *tag = f + pos + 4;
        if (len > 0x7fffffffu || n - pos - 12 < len) {
            return FALLBACK;
        }
        const uint8_t *data = tag + 4;
        uint32_t crc = be32(data + len);
        if ((uint32_t)libdeflate_crc32(0, tag, (size_t)len + 4) != crc) {
            return FALLBACK;
        }
        for (int k = 0; k < 4; k++) {
            uint8_t c = tag[k];
            if (!((c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z'))) {
                return FALLBACK;
            }
        }
        int critical = !(tag[0] & 0x20);
        if (!seen_ihdr) {
            if (memcmp(tag, "IHDR", 4) != 0 || len != 13) {
                return FALLBACK;
            }
            hdr->width = be32(data);
            hdr->height = be32(data + 4);
            hdr->depth = data[8];
            /* gray, deflate, filter method 0, not interlaced; 8 or 16 bits */
            if (hdr->width == 0 || hdr->height == 0 || hdr->width > 0x7fffffffu || hdr->height > 0x7fffffffu
                || (hdr->depth != 8 && hdr->depth != 16) || data[9] != 0 || data[10] != 0 || data[11] != 0
                || data[12] != 0) {
                return FALLBACK;
            }
            seen_ihdr = 1;
        } else if (memcmp(tag, "IDAT", 4) == 0) {
            if (idat_state == 2) {
                return FALLBACK;
            }
            idat_state = 1;
            memmove(f + packed, data, len); /* packed <= pos: the payloads move down, in order */
            packed += len;
        } else if (memcmp(tag, "IEND", 4) == 0) {
            if (len != 0) {
                return FALLBACK;
            }
            seen_iend = 1;
        } else {
            if (critical || memcmp(tag, "IHDR", 4) == 0) {
                return FALLBACK; /* PLTE (or anything critical we do not know) in a gray image, a second IHDR */
            }
            if (idat_state == 1) {
                idat_state = 2;
            }
        }
        pos += (size_t)len + 12;
    }
    if (idat_state == 0) {
        return FALLBACK;
    }
    /* deflate expands at most ~1032x: a header claiming more than the data can hold is not decoded here (and no
       memory is asked for it) */
    uint64_t raw = (uint64_t)hdr->height * ((uint64_t)hdr->width * (uint64_t)(hdr->depth / 8) + 1);
    if (raw / 1032 > (uint64_t)packed + 64) {
        return FALLBACK;
    }
    *idat_len = packed;
    return OK;
}

/* Reads and checks the file, without the GIL: the packed IDAT data is at the start of the scratch file buffer. */
static int load(const char *path, scratch_t *s, header_t *hdr, size_t *idat_len, int *err)
{
    size_t size = 0;
    int rc = read_file(path, s, &size, err);
    if (rc != OK) {
        return rc;
    }
    return parse(s->file, size, hdr, idat_len);
}

/* Inflates and unfilters the loaded image into ``out`` (exactly height x width samples), without the GIL. */
static int unpack(scratch_t *s, const header_t *hdr, size_t idat_len, uint8_t *out, size_t out_len,
                  uint32_t *or_samples)
{
    size_t bpp = (size_t)hdr->depth / 8;
    size_t w = hdr->width, h = hdr->height;
    size_t row_bytes = w * bpp, stride = row_bytes + 1;
    if (h > SIZE_MAX / stride) {
        return FALLBACK;
    }
    if (out_len != w * h * bpp) {
        return NO_MEMORY; /* cannot happen: the caller sized it */
    }
    if (reserve(&s->raw, &s->raw_cap, h * stride) != 0) {
        return NO_MEMORY;
    }
    size_t actual_in = 0;
    enum libdeflate_result r = libdeflate_zlib_decompress_ex(s->inflater, s->file, idat_len, s->raw, h * stride,
                                                             &actual_in, NULL);
    if (r != LIBDEFLATE_SUCCESS || actual_in != idat_len) {
        return FALLBACK; /* corrupt, too little or too much data, or bytes after the zlib stream */
    }
    /* map the destination's pages in one call (a fresh shared frame buffer slot: one fault per page otherwise);
       older kernels refuse, then the pages fault in as they are written */
    long page = sysconf(_SC_PAGESIZE);
    if (page > 0 && out_len >= 4 * (size_t)page) {
        uintptr_t first = ((uintptr_t)out + (uintptr_t)page - 1) & ~((uintptr_t)page - 1);
        uintptr_t last = ((uintptr_t)out + out_len) & ~((uintptr_t)page - 1);
        if (last > first) {
            (void)madvise((void *)first, last - first, MADV_POPULATE_WRITE);
        }
    }
    uint32_t acc = 0;
    const uint8_t *prior = NULL;
    for (size_t y = 0; y < h; y++) {
        uint8_t *row = s->raw + y * stride + 1;
        switch (row[-1]) {
        case 0:
            break;
        case 1:
            unfilter_sub(row, row_bytes, bpp);
            break;
        case 2:
            if (prior != NULL) {
                unfilter_up(row, prior, row_bytes);
            }
            break;
        case 3:
            if (prior != NULL) {
                unfilter_avg(row, prior, row_bytes, bpp);
            } else {
                for (size_t i = bpp; i < row_bytes; i++) {
                    row[i] = (uint8_t)(row[i] + (row[i - bpp] >> 1));
                }
            }
            break;
        case 4:
            if (prior != NULL) {
                unfilter_paeth(row, prior, row_bytes, bpp);
            } else {
                unfilter_sub(row, row_bytes, bpp); /* b = c = 0: the predictor is a */
            }
            break;
        default:
            return FALLBACK;
        }
        if (bpp == 2) {
            acc |= swap_row16(row, (uint16_t *)(void *)(out + y * row_bytes), w);
        } else {
            acc |= copy_row8(row, out + y * row_bytes, w);
        }
        prior = row;
    }
    *or_samples = acc;
    return OK;
}

/* Copies a PNG held in memory into the scratch file buffer and checks it, without the GIL (as ``load``). */
static int load_bytes(const uint8_t *data, size_t n, scratch_t *s, header_t *hdr, size_t *idat_len)
{
    if (reserve(&s->file, &s->file_cap, n + 1) != 0) {
        return NO_MEMORY;
    }
    memcpy(s->file, data, n);
    return parse(s->file, n, hdr, idat_len);
}

/* Inflates a raw deflate stream (a zip member) of ``size`` bytes whose CRC-32 is ``crc`` into the scratch file buffer
   and checks it, without the GIL (as ``load``). Anything that does not inflate to exactly ``size`` bytes of that CRC
   falls back (the caller reads the member another way and reports what is wrong). */
static int load_deflated(const uint8_t *data, size_t n, size_t size, uint32_t crc, scratch_t *s, header_t *hdr,
                         size_t *idat_len)
{
    if (reserve(&s->file, &s->file_cap, size + 1) != 0) {
        return NO_MEMORY;
    }
    size_t actual = 0;
    if (libdeflate_deflate_decompress(s->inflater, data, n, s->file, size, &actual) != LIBDEFLATE_SUCCESS
        || actual != size || (uint32_t)libdeflate_crc32(0, s->file, size) != crc) {
        return FALLBACK;
    }
    return parse(s->file, size, hdr, idat_len);
}

/* Reads exactly n bytes at ``offset`` of ``fd``; FALLBACK when the file ends before (a truncated archive). */
static int read_at(int fd, uint8_t *dst, size_t n, off_t offset, int *err)
{
    size_t got = 0;
    while (got < n) {
        ssize_t r = pread(fd, dst + got, n - got, offset + (off_t)got);
        if (r < 0) {
            if (errno == EINTR) {
                continue;
            }
            *err = errno;
            return OS_ERROR;
        }
        if (r == 0) {
            return FALLBACK;
        }
        got += (size_t)r;
    }
    return OK;
}

/* Reads a zip member's data (``n`` bytes at ``offset`` of ``fd``) into the scratch file buffer, inflating it when
   ``inflated`` >= 0 (a deflated member of that size and CRC-32), and checks the PNG, without the GIL. */
static int load_member(int fd, off_t offset, size_t n, Py_ssize_t inflated, uint32_t crc, scratch_t *s,
                       header_t *hdr, size_t *idat_len, int *err)
{
    if (inflated < 0) {
        if (reserve(&s->file, &s->file_cap, n + 1) != 0) {
            return NO_MEMORY;
        }
        int rc = read_at(fd, s->file, n, offset, err);
        return rc != OK ? rc : parse(s->file, n, hdr, idat_len);
    }
    if (reserve(&s->member, &s->member_cap, n + 1) != 0) {
        return NO_MEMORY;
    }
    int rc = read_at(fd, s->member, n, offset, err);
    return rc != OK ? rc : load_deflated(s->member, n, (size_t)inflated, crc, s, hdr, idat_len);
}

/* decode(path, out) when ``data`` and ``member`` are NULL, decode_bytes(data, out) (``inflated`` < 0) or a deflated
   ``data`` (``inflated`` >= 0), decode_member(...) when ``member`` is given: ``path_obj`` (a bytes object, or NULL)
   names the file for OSError. */
typedef struct {
    int fd;           /* >= 0: a zip member at ``offset``, ``size`` bytes (``inflated`` / ``crc`` as below) */
    off_t offset;
    size_t size;
} member_t;

static PyObject *decode_any(PyObject *path_obj, const Py_buffer *data, Py_ssize_t inflated, uint32_t crc,
                            const member_t *member, PyObject *out_obj)
{
    const char *path = path_obj != NULL ? PyBytes_AS_STRING(path_obj) : NULL;
    Py_buffer out = {0};
    int given = out_obj != Py_None, have_out = given;
    if (given && PyObject_GetBuffer(out_obj, &out, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS) != 0) {
        return NULL;
    }
    header_t hdr = {0, 0, 0};
    uint32_t acc = 0;
    size_t idat_len = 0;
    int err = 0, rc;
    PyObject *fresh = NULL;
    uint8_t *dst = have_out ? (uint8_t *)out.buf : NULL;
    size_t dst_len = have_out ? (size_t)out.len : 0;
    Py_BEGIN_ALLOW_THREADS
    scratch_t *s = scratch_get();
    rc = s == NULL ? NO_MEMORY
         : member != NULL ? load_member(member->fd, member->offset, member->size, inflated, crc, s, &hdr, &idat_len,
                                        &err)
         : data != NULL && inflated >= 0
             ? load_deflated((const uint8_t *)data->buf, (size_t)data->len, (size_t)inflated, crc, s, &hdr, &idat_len)
         : data != NULL ? load_bytes((const uint8_t *)data->buf, (size_t)data->len, s, &hdr, &idat_len)
                        : load(path, s, &hdr, &idat_len, &err);
    if (rc == OK && have_out
        && (out.ndim != 2 || out.shape == NULL || out.shape[0] != (Py_ssize_t)hdr.height
            || out.shape[1] != (Py_ssize_t)hdr.width || out.itemsize != hdr.depth / 8)) {
        have_out = 0; /* ``out`` is not of the image's shape and sample size: leave it alone */
    }
    if (rc == OK && !have_out) {
        /* no destination (or not a fitting one): a new one of the image's size */
        size_t n = (size_t)hdr.width * hdr.height * (size_t)(hdr.depth / 8);
        Py_BLOCK_THREADS
        fresh = n <= (size_t)PY_SSIZE_T_MAX ? PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)n) : NULL;
        Py_UNBLOCK_THREADS
        if (fresh == NULL) {
            rc = NO_MEMORY;
        } else {
            dst = (uint8_t *)PyByteArray_AS_STRING(fresh);
            dst_len = n;
        }
    }
    if (rc == OK) {
        rc = unpack(s, &hdr, idat_len, dst, dst_len, &acc);
    }
    Py_END_ALLOW_THREADS
    if (given) {
        PyBuffer_Release(&out);
    }
    PyObject *result = NULL;
    if (rc == OK) {
        result = Py_BuildValue("(IIiIO)", hdr.height, hdr.width, hdr.depth, acc, have_out ? out_obj : fresh);
    } else if (rc == FALLBACK) {
        result = Py_NewRef(Py_None);
    } else if (rc == OS_ERROR) {
        errno = err;
        result = path_obj != NULL ? PyErr_SetFromErrnoWithFilenameObject(PyExc_OSError, path_obj)
                                  : PyErr_SetFromErrno(PyExc_OSError);
    } else if (!PyErr_Occurred()) {
        PyErr_NoMemory();
    }
    Py_XDECREF(fresh);
    return result;
}

static PyObject *decode(PyObject *self, PyObject *args)
{
    PyObject *path_obj = NULL, *out_obj = NULL;
    (void)self;
    if (!PyArg_ParseTuple(args, "O&O", PyUnicode_FSConverter, &path_obj, &out_obj)) {
        return NULL;
    }
    PyObject *result = decode_any(path_obj, NULL, -1, 0, NULL, out_obj);
    Py_DECREF(path_obj);
    return result;
}

static PyObject *decode_bytes(PyObject *self, PyObject *args)
{
    Py_buffer data = {0};
    PyObject *out_obj = NULL;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*O", &data, &out_obj)) {
        return NULL;
    }
    PyObject *result = decode_any(NULL, &data, -1, 0, NULL, out_obj);
    PyBuffer_Release(&data);
    return result;
}


/* --- encoder of stored (uncompressed deflate) gray PNGs --- */

/* Bytes [b0, b0 + n) of a row of big-endian samples, from native ``src`` samples of ``bpp`` bytes. */
static void put_samples(uint8_t *dst, const uint8_t *src, size_t b0, size_t n, size_t bpp)
{
    if (bpp == 1) {
        memcpy(dst, src + b0, n);
        return;
    }
    const uint16_t *s16 = (const uint16_t *)(const void *)src;
    size_t b = b0, end = b0 + n;
    if ((b & 1) && b < end) { /* the low byte of a sample */
        *dst++ = (uint8_t)(s16[b >> 1] & 0xff);
        b++;
    }
    size_t pairs = (end - b) / 2;
    const uint16_t *p = s16 + (b >> 1);
    for (size_t j = 0; j < pairs; j++) {
        uint16_t v = __builtin_bswap16(p[j]);
        memcpy(dst + 2 * j, &v, 2);
    }
    dst += 2 * pairs;
    b += 2 * pairs;
    if (b < end) { /* the high byte of a sample */
        *dst = (uint8_t)(s16[b >> 1] >> 8);
    }
}

/* The raw (filtered) stream's bytes [off, off + n): each row is filter byte 0 then its big-endian samples. */
static void put_raw(uint8_t *dst, const uint8_t *img, size_t row_bytes, size_t bpp, size_t off, size_t n)
{
    size_t stride = row_bytes + 1;
    while (n > 0) {
        size_t y = off / stride, col = off % stride;
        if (col == 0) {
            *dst++ = 0;
            off++;
            n--;
            continue;
        }
        size_t k = stride - col < n ? stride - col : n;
        put_samples(dst, img + y * row_bytes, col - 1, k, bpp);
        dst += k;
        off += k;
        n -= k;
    }
}

static inline void put_be32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)(v >> 24);
    p[1] = (uint8_t)(v >> 16);
    p[2] = (uint8_t)(v >> 8);
    p[3] = (uint8_t)v;
}

static PyObject *encode_stored(PyObject *self, PyObject *args)
{
    Py_buffer img, head, blocks;
    Py_ssize_t height, width, bpp;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*nnny*y*", &img, &height, &width, &bpp, &head, &blocks)) {
        return NULL;
    }
    const char *error = NULL;
    size_t raw_len = 0, n_blocks = (size_t)blocks.len / 2, sum = 0;
    if (height <= 0 || width <= 0 || (bpp != 1 && bpp != 2)
        || img.len != height * width * bpp || blocks.len % 2 != 0 || n_blocks == 0) {
        error = "image must hold height x width samples of bpp (1 or 2) bytes; blocks uint16 sizes";
    } else {
        raw_len = (size_t)height * ((size_t)width * (size_t)bpp + 1);
        for (size_t i = 0; i < n_blocks; i++) {
            uint16_t L;
            memcpy(&L, (const uint8_t *)blocks.buf + 2 * i, 2);
            sum += L;
        }
        if (sum != raw_len) {
            error = "the stored blocks' sizes do not add up to the raw image";
        }
    }
    PyObject *result = NULL;
    if (error == NULL) {
        /* head (signature + IHDR chunk), IDAT length + tag, zlib header, blocks, Adler-32, IDAT CRC, IEND chunk */
        size_t zlen = 2 + 5 * n_blocks + raw_len + 4;
        size_t total = (size_t)head.len + 8 + zlen + 4 + 12;
        if (zlen > 0x7fffffffu) {
            error = "image too large for one PNG chunk";
        } else {
            result = PyBytes_FromStringAndSize(NULL, (Py_ssize_t)total);
        }
        if (result != NULL) {
            uint8_t *o = (uint8_t *)PyBytes_AS_STRING(result);
            Py_BEGIN_ALLOW_THREADS
            memcpy(o, head.buf, (size_t)head.len);
            uint8_t *chunk = o + head.len;
            put_be32(chunk, (uint32_t)zlen);
            memcpy(chunk + 4, "IDAT", 4);
            uint8_t *z = chunk + 8, *w = z;
            *w++ = 0x78;
            *w++ = 0x01;
            uint32_t adler = 1;
            size_t off = 0;
            for (size_t i = 0; i < n_blocks; i++) {
                uint16_t L;
                memcpy(&L, (const uint8_t *)blocks.buf + 2 * i, 2);
                w[0] = i + 1 == n_blocks ? 1 : 0;
                w[1] = (uint8_t)(L & 0xff);
                w[2] = (uint8_t)(L >> 8);
                w[3] = (uint8_t)(~L & 0xff);
                w[4] = (uint8_t)((uint16_t)~L >> 8);
                w += 5;
                put_raw(w, (const uint8_t *)img.buf, (size_t)width * (size_t)bpp, (size_t)bpp, off, L);
                adler = (uint32_t)libdeflate_adler32(adler, w, L);
                w += L;
                off += L;
            }
            put_be32(w, adler);
            w += 4;
            put_be32(w, (uint32_t)libdeflate_crc32(0, chunk + 4, zlen + 4));
            w += 4;
            static const uint8_t iend[12] = {0, 0, 0, 0, 'I', 'E', 'N', 'D', 0xae, 0x42, 0x60, 0x82};
            memcpy(w, iend, 12);
            Py_END_ALLOW_THREADS
        }
    }
    PyBuffer_Release(&img);
    PyBuffer_Release(&head);
    PyBuffer_Release(&blocks);
    if (error != NULL) {
        PyErr_SetString(PyExc_ValueError, error);
        return NULL;
    }
    return result;
}

static PyObject *decode_member(PyObject *self, PyObject *args)
{
    int fd = -1;
    long long offset = 0;
    Py_ssize_t size = 0, inflated = -1;
    unsigned long crc = 0;
    PyObject *out_obj = NULL;
    (void)self;
    if (!PyArg_ParseTuple(args, "iLnnkO", &fd, &offset, &size, &inflated, &crc, &out_obj)) {
        return NULL;
    }
    if (fd < 0 || offset < 0 || size < 0) {
        PyErr_SetString(PyExc_ValueError, "fd, offset and size must be >= 0");
        return NULL;
    }
    member_t member = {fd, (off_t)offset, (size_t)size};
    return decode_any(NULL, NULL, inflated, (uint32_t)crc, &member, out_obj);
}

static PyMethodDef methods[] = {
    {"decode", decode, METH_VARARGS,
     "decode(path, out) -> (height, width, bit_depth, or_of_samples, buffer) | None\n\n"
     "Decode a gray 8- or 16-bit non-interlaced PNG into ``out`` (a writable C-contiguous 2-D buffer; written only\n"
     "when its shape is (height, width) and its item size the sample size; native byte order), else (also when\n"
     "``out`` is None) into a new bytearray. ``buffer`` is the one written. None when the file is anything else or\n"
     "not valid in every respect (the caller falls back to another decoder). OSError when it cannot be read."},
    {"decode_bytes", decode_bytes, METH_VARARGS,
     "decode_bytes(data, out) -> (height, width, bit_depth, or_of_samples, buffer) | None\n\n"
     "``decode`` of a whole PNG file held in ``data`` (a bytes-like object, e.g. a member read from a zip)."},
    {"decode_member", decode_member, METH_VARARGS,
     "decode_member(fd, offset, size, inflated, crc32, out) -> (height, width, bit_depth, or_of_samples, buffer) | None\n\n"
     "``decode`` of a zip member's PNG: its ``size`` bytes of data at ``offset`` of the open file ``fd``, stored\n"
     "(``inflated`` -1) or deflated (``inflated``: its size, ``crc32``: its CRC-32). None also when the file ends\n"
     "before the data or the data does not inflate to ``inflated`` bytes of that CRC."},
    {"encode_stored", encode_stored, METH_VARARGS,
     "encode_stored(image, height, width, bpp, head, blocks) -> bytes\n\n"
     "A whole PNG file: ``head`` (signature and IHDR chunk), one IDAT chunk holding the zlib stream of stored\n"
     "deflate blocks of the sizes in ``blocks`` (native uint16 each; they add up to the raw image: each row its\n"
     "filter byte 0 and its big-endian samples) with its Adler-32, then IEND. ``image``: C-contiguous native\n"
     "samples of ``bpp`` (1 or 2) bytes. The GIL is released while it works."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_pngcodec",
                                    "A decoder for gray 8/16-bit PNGs, an encoder of stored ones.", -1,
                                    methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__pngcodec(void)
{
    static int key_made = 0;
    if (!key_made) {
        if (pthread_key_create(&scratch_key, scratch_free) != 0) {
            PyErr_SetString(PyExc_RuntimeError, "cannot create the decoder's thread-local key");
            return NULL;
        }
        key_made = 1;
    }
    return PyModule_Create(&module);
}
