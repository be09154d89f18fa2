/*
 * Host test harness of the C codec: runs the shared vectors (converted to a line format by
 * `python -m bracketry.wire.vectors --c-text`, see host/bracketry/wire/vectors.py: to_c_text) plus built-in checks.
 * Build: gcc -std=c99 -Wall -Wextra -Werror -fsanitize=address,undefined bproto.c bproto_test.c -o bproto_test
 * Run:   ./bproto_test vectors.txt      (prints one line per failure and a summary; exit 0 only if all pass)
 */
#include "bproto.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define LINE_MAX_CHARS 16384
#define BYTES_MAX 8192

static int failures = 0;
static int checks = 0;

static void fail(const char *what, const char *detail)
{
    failures++;
    printf("FAIL %s: %s\n", what, detail);
}

static int hexval(char c)
{
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

/* "-" is empty; returns byte count or -1 */
static long parse_hex(const char *s, uint8_t *out, size_t cap)
{
    if (strcmp(s, "-") == 0) return 0;
    size_t n = strlen(s);
    if (n % 2 != 0 || n / 2 > cap) return -1;
    for (size_t i = 0; i < n / 2; i++) {
        int hi = hexval(s[2 * i]), lo = hexval(s[2 * i + 1]);
        if (hi < 0 || lo < 0) return -1;
        out[i] = (uint8_t)(hi * 16 + lo);
    }
    return (long)(n / 2);
}

static uint8_t a[BYTES_MAX], b[BYTES_MAX], c[BYTES_MAX];

/* stream state */
static char stream_name[256];
static bproto_decoder_t dec;
static bproto_frame_t got[64];
static int n_got = 0, n_expected = 0;

static void check_crc(char *args)
{
    char *data = strtok(args, " "), *crc = strtok(NULL, " ");
    long n = parse_hex(data, a, sizeof a);
    checks++;
    if (n < 0 || crc == NULL) { fail("C", "bad line"); return; }
    if (bproto_crc16(a, (size_t)n) != (uint16_t)strtoul(crc, NULL, 10)) fail("crc16", data);
}

static void check_cobs(char *args)
{
    char *dec_hex = strtok(args, " "), *enc_hex = strtok(NULL, " ");
    long nd = parse_hex(dec_hex, a, sizeof a), ne = parse_hex(enc_hex, b, sizeof b);
    checks++;
    if (nd < 0 || ne < 0) { fail("B", "bad line"); return; }
    size_t w = bproto_cobs_encode(a, (size_t)nd, c, sizeof c);
    if (w != (size_t)ne || memcmp(c, b, w) != 0) fail("cobs_encode", dec_hex);
    long r = bproto_cobs_decode(b, (size_t)ne, c, sizeof c);
    if (r != nd || memcmp(c, a, (size_t)nd) != 0) fail("cobs_decode", enc_hex);
    /* in place */
    memcpy(c, b, (size_t)ne);
    r = bproto_cobs_decode(c, (size_t)ne, c, sizeof c);
    if (r != nd || memcmp(c, a, (size_t)nd) != 0) fail("cobs_decode in place", enc_hex);
}

static void check_encode(char *args)
{
    char *type = strtok(args, " "), *seq = strtok(NULL, " "), *pl = strtok(NULL, " "), *fr = strtok(NULL, " ");
    long np = parse_hex(pl, a, sizeof a), nf = parse_hex(fr, b, sizeof b);
    checks++;
    if (np < 0 || nf < 0 || type == NULL || seq == NULL) { fail("E", "bad line"); return; }
    uint8_t out[BPROTO_MAX_FRAME];
    size_t w = bproto_encode_frame((uint8_t)atoi(type), (uint16_t)atoi(seq), a, (size_t)np, out, sizeof out);
    if (w != (size_t)nf || memcmp(out, b, w) != 0) fail("encode_frame", fr);
    /* decode it back byte by byte */
    bproto_decoder_t d;
    bproto_frame_t f;
    int ok = 0;
    bproto_decoder_init(&d);
    for (long i = 0; i < nf; i++) ok += bproto_decoder_feed(&d, b[i], &f);
    if (ok != 1 || f.type != (uint8_t)atoi(type) || f.seq != (uint16_t)atoi(seq) || f.len != (uint16_t)np ||
        memcmp(f.payload, a, (size_t)np) != 0 || f.ver != BPROTO_VERSION)
        fail("decode of encoded frame", fr);
    /* too small output buffer -> 0 */
    if (bproto_encode_frame((uint8_t)atoi(type), 0, a, (size_t)np, out, (size_t)nf - 1) != 0)
        fail("encode_frame into a short buffer must return 0", fr);
}

static void stream_start(char *args)
{
    snprintf(stream_name, sizeof stream_name, "%.200s", args);
    bproto_decoder_init(&dec);
    n_got = 0;
    n_expected = 0;
}

static void stream_chunk(char *args)
{
    long n = parse_hex(args, a, sizeof a);
    if (n < 0) { fail(stream_name, "bad chunk"); return; }
    for (long i = 0; i < n; i++) {
        bproto_frame_t f;
        if (bproto_decoder_feed(&dec, a[i], &f)) {
            if (n_got < 64) got[n_got] = f;
            n_got++;
        }
    }
}

static void stream_frame(char *args)
{
    char *type = strtok(args, " "), *seq = strtok(NULL, " "), *pl = strtok(NULL, " ");
    long np = parse_hex(pl, a, sizeof a);
    char detail[300];
    int i = n_expected++;
    checks++;
    snprintf(detail, sizeof detail, "frame %d", i);
    if (i >= n_got || i >= 64) { fail(stream_name, "missing frame"); return; }
    if (got[i].type != (uint8_t)atoi(type) || got[i].seq != (uint16_t)atoi(seq) || got[i].len != (uint16_t)np ||
        memcmp(got[i].payload, a, (size_t)np) != 0)
        fail(stream_name, detail);
}

static void stream_end(char *args)
{
    unsigned long v[7];
    int k = 0;
    for (char *t = strtok(args, " "); t != NULL && k < 7; t = strtok(NULL, " ")) v[k++] = strtoul(t, NULL, 10);
    checks++;
    if (k != 7) { fail(stream_name, "bad X line"); return; }
    if (n_got != n_expected) fail(stream_name, "frame count differs");
    unsigned long have[7] = {dec.frames_ok, dec.crc_errors, dec.length_errors, dec.cobs_errors, dec.version_errors,
                             dec.overflows, dec.bytes_discarded};
    static const char *names[7] = {"frames_ok", "crc_errors", "length_errors", "cobs_errors", "version_errors",
                                   "overflows", "bytes_discarded"};
    for (int i = 0; i < 7; i++) {
        if (have[i] != v[i]) {
            char detail[200];
            snprintf(detail, sizeof detail, "%s = %lu, expected %lu", names[i], have[i], v[i]);
            fail(stream_name, detail);
        }
    }
}

/* the NACK code a device would send for a command payload (0 = structurally fine) */
static uint8_t nack_for(uint8_t type, const uint8_t *p, size_t n)
{
    int want = bproto_expected_len(type);
    if (want == -2) return BPROTO_NACK_UNKNOWN_TYPE;
    if (want == -1) return bproto_set_brackets_len_ok(p, n) ? 0 : BPROTO_NACK_BAD_LENGTH;
    if (type == BPROTO_MSG_HELLO && n == BPROTO_LEN_HELLO) return 0;
    return (size_t)want == n ? 0 : BPROTO_NACK_BAD_LENGTH;
}

static void check_payload(char *args)
{
    char *type = strtok(args, " "), *pl = strtok(NULL, " "), *nack = strtok(NULL, " ");
    long np = parse_hex(pl, a, sizeof a);
    checks++;
    if (np < 0 || nack == NULL) { fail("P", "bad line"); return; }
    if (nack_for((uint8_t)atoi(type), a, (size_t)np) != (uint8_t)atoi(nack)) fail("payload check", pl);
}

static void check_brackets(char *args)
{
    uint32_t exp_us[64];
    size_t n = 0;
    char *period = strtok(args, " "), *nack = strtok(NULL, " ");
    checks++;
    if (period == NULL || nack == NULL) { fail("R", "bad line"); return; }
    for (char *t = strtok(NULL, " "); t != NULL && n < 64; t = strtok(NULL, " ")) exp_us[n++] = (uint32_t)strtoul(t, NULL, 10);
    if (bproto_check_set_brackets((uint32_t)strtoul(period, NULL, 10), exp_us, n) != (uint8_t)atoi(nack))
        fail("set_brackets check", period);
}

static void builtin_checks(void)
{
    uint8_t p[8];
    checks++;
    if (bproto_crc16((const uint8_t *)"123456789", 9) != 0x29B1u) fail("builtin", "crc check value");
    bproto_put_u64(p, 0x0102030405060708ull);
    if (p[0] != 8 || p[7] != 1 || bproto_get_u64(p) != 0x0102030405060708ull) fail("builtin", "u64");
    bproto_put_u32(p, 0xA1B2C3D4u);
    if (p[0] != 0xD4 || bproto_get_u32(p) != 0xA1B2C3D4u) fail("builtin", "u32");
    bproto_put_u16(p, 0xBEEF);
    if (p[0] != 0xEF || bproto_get_u16(p) != 0xBEEF) fail("builtin", "u16");
    uint8_t big[BPROTO_MAX_PAYLOAD + 1] = {0};
    uint8_t out[BPROTO_MAX_FRAME];
    if (bproto_encode_frame(1, 1, big, sizeof big, out, sizeof out) != 0) fail("builtin", "256-byte payload");
    if (bproto_encode_frame(1, 1, NULL, 3, out, sizeof out) != 0) fail("builtin", "NULL payload");
    memset(big, 0xFF, sizeof big);
    if (bproto_encode_frame(0xFF, 0xFFFF, big, BPROTO_MAX_PAYLOAD, out, sizeof out) == 0) fail("builtin", "max");
}

int main(int argc, char **argv)
{
    FILE *fp = argc > 1 ? fopen(argv[1], "r") : stdin;
    static char line[LINE_MAX_CHARS];
    if (fp == NULL) {
        perror("open vectors");
        return 2;
    }
    builtin_checks();
    while (fgets(line, sizeof line, fp) != NULL) {
        size_t n = strlen(line);
        while (n > 0 && (line[n - 1] == '\n' || line[n - 1] == '\r')) line[--n] = 0;
        if (n < 2) continue;
        char *args = line + 2;
        switch (line[0]) {
        case 'C': check_crc(args); break;
        case 'B': check_cobs(args); break;
        case 'E': check_encode(args); break;
        case 'S': stream_start(args); break;
        case 'K': stream_chunk(args); break;
        case 'F': stream_frame(args); break;
        case 'X': stream_end(args); break;
        case 'P': check_payload(args); break;
        case 'R': check_brackets(args); break;
        default: fail("line", line); break;
        }
    }
    if (fp != stdin) fclose(fp);
    printf("%s: %d checks, %d failures\n", failures ? "FAIL" : "PASS", checks, failures);
    return failures ? 1 : 0;
}
