/*
 * Fuzz harness of the C decoder (host build, run under AddressSanitizer/UBSan by benchmarks/bench_wire_fuzz.py).
 *
 * stdin: records, each a u32 little-endian length followed by that many bytes. Every record is fed byte by byte to a
 * fresh decoder. Each decoded frame is re-encoded and decoded again (must round-trip, else abort()).
 * stdout: one line per record: "frames_ok crc_errors length_errors cobs_errors version_errors overflows
 * bytes_discarded fnv32" where fnv32 is FNV-1a over (type, seq lo, seq hi, len lo, len hi, payload) of every frame.
 *
 * With -DBPROTO_LIBFUZZER (clang -fsanitize=fuzzer) it instead provides LLVMFuzzerTestOneInput.
 */
#include "bproto.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static uint32_t fnv(uint32_t h, uint8_t b)
{
    return (h ^ b) * 16777619u;
}

static void check_round_trip(const bproto_frame_t *f)
{
    uint8_t out[BPROTO_MAX_FRAME];
    size_t n = bproto_encode_frame(f->type, f->seq, f->payload, f->len, out, sizeof out);
    if (n == 0 || n > BPROTO_MAX_FRAME) abort();
    bproto_decoder_t d;
    bproto_frame_t g;
    int got = 0;
    bproto_decoder_init(&d);
    for (size_t i = 0; i < n; i++) got += bproto_decoder_feed(&d, out[i], &g);
    if (got != 1 || g.type != f->type || g.seq != f->seq || g.len != f->len ||
        memcmp(g.payload, f->payload, f->len) != 0)
        abort();
}

static uint32_t run_record(const uint8_t *data, size_t len, bproto_decoder_t *d)
{
    bproto_frame_t f;
    uint32_t h = 2166136261u;
    bproto_decoder_init(d);
    for (size_t i = 0; i < len; i++) {
        if (bproto_decoder_feed(d, data[i], &f)) {
            if (f.ver != BPROTO_VERSION || f.len > BPROTO_MAX_PAYLOAD) abort();
            check_round_trip(&f);
            h = fnv(h, f.type);
            h = fnv(h, (uint8_t)f.seq);
            h = fnv(h, (uint8_t)(f.seq >> 8));
            h = fnv(h, (uint8_t)f.len);
            h = fnv(h, (uint8_t)(f.len >> 8));
            for (uint16_t k = 0; k < f.len; k++) h = fnv(h, f.payload[k]);
        }
    }
    return h;
}

#ifdef BPROTO_LIBFUZZER
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    bproto_decoder_t d;
    (void)run_record(data, size, &d);
    return 0;
}
#else
int main(void)
{
    static uint8_t buf[1u << 20];
    uint8_t hdr[4];
    bproto_decoder_t d;
    unsigned long records = 0;
    while (fread(hdr, 1, 4, stdin) == 4) {
        uint32_t n = bproto_get_u32(hdr);
        if (n > sizeof buf || fread(buf, 1, n, stdin) != n) {
            fprintf(stderr, "bad record %lu\n", records);
            return 2;
        }
        uint32_t h = run_record(buf, n, &d);
        printf("%lu %lu %lu %lu %lu %lu %lu %lu\n", (unsigned long)d.frames_ok, (unsigned long)d.crc_errors,
               (unsigned long)d.length_errors, (unsigned long)d.cobs_errors, (unsigned long)d.version_errors,
               (unsigned long)d.overflows, (unsigned long)d.bytes_discarded, (unsigned long)h);
        records++;
    }
    fprintf(stderr, "%lu records\n", records);
    return 0;
}
#endif
