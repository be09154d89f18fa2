/*
 * Host test harness of the C codec: runs the shared vectors (converted to a line format by
 * `python -m bracketry_rig.wire.vectors --c-text`, see host/bracketry_rig/wire/vectors.py: to_c_text) plus built-in checks.
 * Every valid-frame vector is decoded, unpacked into its message struct and compared field by field with the
 * vector's fields, then packed again (from the vector's fields and from the decoded struct) and compared byte for
 * byte; every payload_errors vector must give its NACK code from bproto_unpack_msg.
 * Build: gcc -std=c99 -Wall -Wextra -Werror -fsanitize=address,undefined bproto.c bproto_test.c -o bproto_test
 * Run:   ./bproto_test vectors.txt      (prints one line per failure and a summary; exit 0 only if all pass)
 */
#include "bproto.h"

#include <stddef.h>
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

/* the NACK code for a command payload from the structural helpers alone (0 = structurally fine) */
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
    uint8_t want = (uint8_t)atoi(nack);
    bproto_msg_t m;
    if (bproto_unpack_msg((uint8_t)atoi(type), a, (size_t)np, &m) != want) fail("unpack_msg nack", pl);
    /* the length helpers know no value rules (BAD_VALUE payloads have the right length) */
    if (nack_for((uint8_t)atoi(type), a, (size_t)np) != (want == BPROTO_NACK_BAD_VALUE ? 0 : want))
        fail("payload length check", pl);
}

/* ------------------------------------------------------------------ message fields (M lines, see to_c_text) */
enum { FK_U8, FK_U16, FK_U32, FK_U64, FK_UID, FK_MESSAGE, FK_EXPOSURES };

typedef struct {
    uint8_t type;
    const char *name; /* as in the vectors' "fields" (the Python field names) */
    int kind;
    size_t off; /* offset in bproto_msg_t */
} field_desc_t;

static const field_desc_t field_table[] = {
    {BPROTO_MSG_HELLO, "device_kind", FK_U8, offsetof(bproto_msg_t, u.hello.device_kind)},
    {BPROTO_MSG_HELLO, "proto_minor", FK_U8, offsetof(bproto_msg_t, u.hello.proto_minor)},
    {BPROTO_MSG_HELLO, "fw_major", FK_U8, offsetof(bproto_msg_t, u.hello.fw_major)},
    {BPROTO_MSG_HELLO, "fw_minor", FK_U8, offsetof(bproto_msg_t, u.hello.fw_minor)},
    {BPROTO_MSG_HELLO, "fw_patch", FK_U8, offsetof(bproto_msg_t, u.hello.fw_patch)},
    {BPROTO_MSG_HELLO, "uid", FK_UID, offsetof(bproto_msg_t, u.hello.uid)},
    {BPROTO_MSG_HELLO, "capabilities", FK_U32, offsetof(bproto_msg_t, u.hello.capabilities)},
    {BPROTO_MSG_ACK, "acked_seq", FK_U16, offsetof(bproto_msg_t, u.ack.acked_seq)},
    {BPROTO_MSG_NACK, "acked_seq", FK_U16, offsetof(bproto_msg_t, u.nack.acked_seq)},
    {BPROTO_MSG_NACK, "code", FK_U8, offsetof(bproto_msg_t, u.nack.code)},
    {BPROTO_MSG_HEARTBEAT, "uptime_ms", FK_U32, offsetof(bproto_msg_t, u.heartbeat.uptime_ms)},
    {BPROTO_MSG_HEARTBEAT, "state", FK_U8, offsetof(bproto_msg_t, u.heartbeat.state)},
    {BPROTO_MSG_PING, "host_time_ns", FK_U64, offsetof(bproto_msg_t, u.ping.host_time_ns)},
    {BPROTO_MSG_PONG, "host_time_ns", FK_U64, offsetof(bproto_msg_t, u.pong.host_time_ns)},
    {BPROTO_MSG_PONG, "device_time_us", FK_U64, offsetof(bproto_msg_t, u.pong.device_time_us)},
    {BPROTO_MSG_SET_BRACKETS, "period_us", FK_U32, offsetof(bproto_msg_t, u.set_brackets.period_us)},
    {BPROTO_MSG_SET_BRACKETS, "exposures_us", FK_EXPOSURES, offsetof(bproto_msg_t, u.set_brackets)},
    {BPROTO_MSG_START, "session_id", FK_U32, offsetof(bproto_msg_t, u.start.session_id)},
    {BPROTO_MSG_TRIGGER, "session_id", FK_U32, offsetof(bproto_msg_t, u.trigger.session_id)},
    {BPROTO_MSG_TRIGGER, "trigger_seq", FK_U32, offsetof(bproto_msg_t, u.trigger.trigger_seq)},
    {BPROTO_MSG_TRIGGER, "bracket_index", FK_U8, offsetof(bproto_msg_t, u.trigger.bracket_index)},
    {BPROTO_MSG_TRIGGER, "exposure_us", FK_U32, offsetof(bproto_msg_t, u.trigger.exposure_us)},
    {BPROTO_MSG_TRIGGER, "t_start_us", FK_U64, offsetof(bproto_msg_t, u.trigger.t_start_us)},
    {BPROTO_MSG_PANEL_STATE, "cam_left", FK_U8, offsetof(bproto_msg_t, u.panel_state.cam_left)},
    {BPROTO_MSG_PANEL_STATE, "cam_right", FK_U8, offsetof(bproto_msg_t, u.panel_state.cam_right)},
    {BPROTO_MSG_PANEL_STATE, "trigger", FK_U8, offsetof(bproto_msg_t, u.panel_state.trigger)},
    {BPROTO_MSG_PANEL_STATE, "imu", FK_U8, offsetof(bproto_msg_t, u.panel_state.imu)},
    {BPROTO_MSG_PANEL_STATE, "lidar", FK_U8, offsetof(bproto_msg_t, u.panel_state.lidar)},
    {BPROTO_MSG_PANEL_STATE, "gnss", FK_U8, offsetof(bproto_msg_t, u.panel_state.gnss)},
    {BPROTO_MSG_PANEL_STATE, "free_disk_mb", FK_U32, offsetof(bproto_msg_t, u.panel_state.free_disk_mb)},
    {BPROTO_MSG_PANEL_STATE, "fps_left_centi", FK_U16, offsetof(bproto_msg_t, u.panel_state.fps_left_centi)},
    {BPROTO_MSG_PANEL_STATE, "fps_right_centi", FK_U16, offsetof(bproto_msg_t, u.panel_state.fps_right_centi)},
    {BPROTO_MSG_PANEL_STATE, "rec_seconds", FK_U32, offsetof(bproto_msg_t, u.panel_state.rec_seconds)},
    {BPROTO_MSG_PANEL_STATE, "message", FK_MESSAGE, offsetof(bproto_msg_t, u.panel_state.message)},
    {BPROTO_MSG_BUTTON, "button", FK_U8, offsetof(bproto_msg_t, u.button.button)},
    {BPROTO_MSG_BUTTON, "action", FK_U8, offsetof(bproto_msg_t, u.button.action)},
    {BPROTO_MSG_BUTTON, "event_seq", FK_U16, offsetof(bproto_msg_t, u.button.event_seq)},
};
#define N_FIELDS (sizeof field_table / sizeof field_table[0])

static uint64_t get_uint(const bproto_msg_t *m, const field_desc_t *d)
{
    const uint8_t *p = (const uint8_t *)m + d->off;
    uint8_t v8;
    uint16_t v16;
    uint32_t v32;
    uint64_t v64;
    switch (d->kind) {
    case FK_U8: memcpy(&v8, p, sizeof v8); return v8;
    case FK_U16: memcpy(&v16, p, sizeof v16); return v16;
    case FK_U32: memcpy(&v32, p, sizeof v32); return v32;
    default: memcpy(&v64, p, sizeof v64); return v64;
    }
}

/* decimal without sign, whole token, <= max */
static int parse_uint(const char *s, uint64_t max, uint64_t *out)
{
    char *end = NULL;
    if (s[0] < '0' || s[0] > '9') return -1;
    unsigned long long v = strtoull(s, &end, 10);
    if (end == NULL || *end != '\0' || v > max) return -1;
    *out = (uint64_t)v;
    return 0;
}

/* Set one field of *m from its text in an M line; -1 if the text does not fit the field. */
static int set_field(bproto_msg_t *m, const field_desc_t *d, char *value)
{
    uint8_t *p = (uint8_t *)m + d->off;
    uint64_t v;
    switch (d->kind) {
    case FK_U8: {
        if (parse_uint(value, 0xFFu, &v) != 0) return -1;
        uint8_t x = (uint8_t)v;
        memcpy(p, &x, sizeof x);
        return 0;
    }
    case FK_U16: {
        if (parse_uint(value, 0xFFFFu, &v) != 0) return -1;
        uint16_t x = (uint16_t)v;
        memcpy(p, &x, sizeof x);
        return 0;
    }
    case FK_U32: {
        if (parse_uint(value, 0xFFFFFFFFu, &v) != 0) return -1;
        uint32_t x = (uint32_t)v;
        memcpy(p, &x, sizeof x);
        return 0;
    }
    case FK_U64:
        if (parse_uint(value, UINT64_MAX, &v) != 0) return -1;
        memcpy(p, &v, sizeof v);
        return 0;
    case FK_UID:
        return parse_hex(value, p, BPROTO_UID_LEN) == (long)BPROTO_UID_LEN ? 0 : -1;
    case FK_MESSAGE: {
        uint8_t text[BPROTO_PANEL_MESSAGE_LEN];
        long n = parse_hex(value, text, sizeof text);
        if (n < 0) return -1;
        memset(m->u.panel_state.message, 0, sizeof m->u.panel_state.message);
        memcpy(m->u.panel_state.message, text, (size_t)n);
        return 0;
    }
    case FK_EXPOSURES: {
        bproto_set_brackets_t *sb = &m->u.set_brackets;
        sb->n = 0;
        if (strcmp(value, "-") == 0) return 0;
        for (char *t = value; t != NULL;) {
            char *comma = strchr(t, ',');
            if (comma != NULL) *comma = '\0';
            if (sb->n >= BPROTO_SET_BRACKETS_MAX_N || parse_uint(t, 0xFFFFFFFFu, &v) != 0) return -1;
            sb->exposures_us[sb->n++] = (uint32_t)v;
            t = comma != NULL ? comma + 1 : NULL;
        }
        return 0;
    }
    default: return -1;
    }
}

static int field_equal(const bproto_msg_t *x, const bproto_msg_t *y, const field_desc_t *d)
{
    switch (d->kind) {
    case FK_UID: return memcmp(x->u.hello.uid, y->u.hello.uid, BPROTO_UID_LEN) == 0;
    case FK_MESSAGE: return strcmp(x->u.panel_state.message, y->u.panel_state.message) == 0;
    case FK_EXPOSURES:
        return x->u.set_brackets.n == y->u.set_brackets.n &&
               memcmp(x->u.set_brackets.exposures_us, y->u.set_brackets.exposures_us,
                      sizeof(uint32_t) * x->u.set_brackets.n) == 0;
    default: return get_uint(x, d) == get_uint(y, d);
    }
}

/* M <type> <seq> <frame hex> <payload hex|-> [<field>=<value> ...]: a valid frame of a message with its fields.
 * Decode the frame, unpack its payload and compare every field; pack the vector's fields and the decoded struct and
 * compare the bytes; encode the re-packed payload and compare the frame. */
static void check_message(char *args)
{
    char *type_s = strtok(args, " "), *seq_s = strtok(NULL, " "), *fr = strtok(NULL, " "), *pl = strtok(NULL, " ");
    char name[128];
    checks++;
    if (type_s == NULL || seq_s == NULL || fr == NULL || pl == NULL) { fail("M", "bad line"); return; }
    uint8_t type = (uint8_t)atoi(type_s);
    uint16_t seq = (uint16_t)atoi(seq_s);
    long nf = parse_hex(fr, b, sizeof b), np = parse_hex(pl, a, sizeof a);
    snprintf(name, sizeof name, "message type %u seq %u", (unsigned)type, (unsigned)seq);
    if (nf < 0 || np < 0) { fail(name, "bad hex"); return; }

    /* the expected struct from the vector's fields */
    bproto_msg_t want, dec_msg;
    memset(&want, 0, sizeof want);
    want.type = type;
    int seen[N_FIELDS] = {0};
    int n_given = 0;
    for (char *t = strtok(NULL, " "); t != NULL; t = strtok(NULL, " ")) {
        char *eq = strchr(t, '=');
        if (eq == NULL) { fail(name, "field without '='"); return; }
        *eq = '\0';
        size_t k = 0;
        while (k < N_FIELDS && !(field_table[k].type == type && strcmp(field_table[k].name, t) == 0)) k++;
        if (k == N_FIELDS) { fail(name, "unknown field in the vector"); return; }
        if (seen[k]++) { fail(name, "field given twice"); return; }
        if (set_field(&want, &field_table[k], eq + 1) != 0) { fail(name, "field value does not fit"); return; }
        n_given++;
    }
    want.hello_request = (uint8_t)(type == BPROTO_MSG_HELLO && n_given == 0);
    for (size_t k = 0; k < N_FIELDS; k++) {
        if (field_table[k].type == type && !seen[k] && !want.hello_request) {
            char detail[200];
            snprintf(detail, sizeof detail, "the vector lacks field %s", field_table[k].name);
            fail(name, detail);
        }
    }

    /* frame bytes -> frame -> fields */
    bproto_decoder_t d;
    bproto_frame_t f;
    int ok = 0;
    bproto_decoder_init(&d);
    for (long i = 0; i < nf; i++) ok += bproto_decoder_feed(&d, b[i], &f);
    if (ok != 1 || f.type != type || f.seq != seq || f.len != (uint16_t)np || memcmp(f.payload, a, (size_t)np) != 0) {
        fail(name, "frame does not decode to the vector's type/seq/payload");
        return;
    }
    memset(&dec_msg, 0xA5, sizeof dec_msg); /* no field may keep a stale value */
    uint8_t rc = bproto_unpack_msg(type, f.payload, f.len, &dec_msg);
    if (rc != 0) { fail(name, "unpack rejected a valid payload"); return; }
    if (dec_msg.type != type || dec_msg.hello_request != want.hello_request) fail(name, "unpacked type/hello_request");
    for (size_t k = 0; k < N_FIELDS; k++) {
        if (field_table[k].type == type && !want.hello_request && !field_equal(&dec_msg, &want, &field_table[k])) {
            char detail[200];
            snprintf(detail, sizeof detail, "decoded field %s differs from the vector", field_table[k].name);
            fail(name, detail);
        }
    }

    /* fields -> payload (from the vector's fields, and re-packed from the decoded struct) -> frame */
    uint8_t p1[BPROTO_MAX_PAYLOAD], p2[BPROTO_MAX_PAYLOAD], out[BPROTO_MAX_FRAME];
    int n1 = bproto_pack_msg(&want, p1, sizeof p1), n2 = bproto_pack_msg(&dec_msg, p2, sizeof p2);
    if (n1 != (int)np || memcmp(p1, a, (size_t)np) != 0) fail(name, "pack of the vector's fields differs");
    if (n2 != (int)np || memcmp(p2, a, (size_t)np) != 0) fail(name, "re-pack of the decoded fields differs");
    if (n2 >= 0) {
        size_t w = bproto_encode_frame(type, seq, p2, (size_t)n2, out, sizeof out);
        if (w != (size_t)nf || memcmp(out, b, w) != 0) fail(name, "frame of the re-packed payload differs");
    }
    if (np > 0 && bproto_pack_msg(&want, p1, (size_t)np - 1u) != -1) fail(name, "pack into a short buffer");

    /* one byte less or more is the wrong length for every layout */
    uint8_t longer[BPROTO_MAX_PAYLOAD + 1];
    memcpy(longer, a, (size_t)np);
    longer[np] = 0x20;
    if (np > 0 && bproto_unpack_msg(type, a, (size_t)np - 1u, &dec_msg) != BPROTO_NACK_BAD_LENGTH)
        fail(name, "payload one byte short not BAD_LENGTH");
    if (bproto_unpack_msg(type, longer, (size_t)np + 1u, &dec_msg) != BPROTO_NACK_BAD_LENGTH)
        fail(name, "payload one byte long not BAD_LENGTH");
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

static void builtin_message_checks(void)
{
    bproto_msg_t m, g;
    uint8_t p[BPROTO_MAX_PAYLOAD + 1];
    checks++;
    /* PANEL_STATE message: printable ASCII, <= 20 characters, space padded, trailing spaces stripped */
    memset(&m, 0, sizeof m);
    m.type = BPROTO_MSG_PANEL_STATE;
    strcpy(m.u.panel_state.message, "  A B  ");
    if (bproto_pack_msg(&m, p, sizeof p) != (int)BPROTO_LEN_PANEL_STATE || memcmp(&p[18], "  A B               ", 20))
        fail("builtin", "message padding");
    if (bproto_unpack_msg(BPROTO_MSG_PANEL_STATE, p, BPROTO_LEN_PANEL_STATE, &g) != 0 ||
        strcmp(g.u.panel_state.message, "  A B") != 0)
        fail("builtin", "message trailing spaces");
    memset(&p[18], ' ', 20);
    if (bproto_unpack_msg(BPROTO_MSG_PANEL_STATE, p, BPROTO_LEN_PANEL_STATE, &g) != 0 || g.u.panel_state.message[0])
        fail("builtin", "blank message");
    strcpy(m.u.panel_state.message, "12345678901234567890");
    if (bproto_pack_msg(&m, p, sizeof p) != (int)BPROTO_LEN_PANEL_STATE ||
        bproto_unpack_msg(BPROTO_MSG_PANEL_STATE, p, BPROTO_LEN_PANEL_STATE, &g) != 0 ||
        strcmp(g.u.panel_state.message, "12345678901234567890") != 0)
        fail("builtin", "20-character message");
    static const uint8_t bad_bytes[] = {0x00, 0x07, 0x1F, 0x7F, 0x80, 0xE9, 0xFF};
    for (size_t i = 0; i < sizeof bad_bytes; i++) {
        memset(&p[18], 'x', 20);
        p[18 + 3] = bad_bytes[i];
        if (bproto_unpack_msg(BPROTO_MSG_PANEL_STATE, p, BPROTO_LEN_PANEL_STATE, &g) != BPROTO_NACK_BAD_VALUE)
            fail("builtin", "non-printable message byte must be BAD_VALUE");
        if (bad_bytes[i] != 0) {
            strcpy(m.u.panel_state.message, "abc");
            m.u.panel_state.message[1] = (char)bad_bytes[i];
            if (bproto_pack_msg(&m, p, sizeof p) != -1) fail("builtin", "pack of a non-printable message");
        }
    }
    memset(m.u.panel_state.message, 'y', sizeof m.u.panel_state.message); /* 21 characters, no terminator */
    if (bproto_pack_msg(&m, p, sizeof p) != -1) fail("builtin", "pack of a 21-character message");
    /* SET_BRACKETS: up to 62 entries fit a payload; unpack is structural (value rules: check_set_brackets) */
    memset(&m, 0, sizeof m);
    m.type = BPROTO_MSG_SET_BRACKETS;
    m.u.set_brackets.period_us = 5000u;
    m.u.set_brackets.n = (uint8_t)BPROTO_SET_BRACKETS_MAX_N;
    for (uint32_t i = 0; i < BPROTO_SET_BRACKETS_MAX_N; i++) m.u.set_brackets.exposures_us[i] = 100u + i;
    if (bproto_pack_msg(&m, p, sizeof p) != (int)(5u + 4u * BPROTO_SET_BRACKETS_MAX_N) ||
        bproto_unpack_msg(BPROTO_MSG_SET_BRACKETS, p, 5u + 4u * BPROTO_SET_BRACKETS_MAX_N, &g) != 0 ||
        g.u.set_brackets.n != BPROTO_SET_BRACKETS_MAX_N || g.u.set_brackets.exposures_us[61] != 161u)
        fail("builtin", "SET_BRACKETS with 62 entries");
    m.u.set_brackets.n = (uint8_t)(BPROTO_SET_BRACKETS_MAX_N + 1u);
    if (bproto_pack_msg(&m, p, sizeof p) != -1) fail("builtin", "SET_BRACKETS with 63 entries");
    p[0] = 0x10; p[1] = 0x27; p[2] = 0; p[3] = 0; p[4] = 0;
    if (bproto_unpack_msg(BPROTO_MSG_SET_BRACKETS, p, 5, &g) != 0 || g.u.set_brackets.n != 0)
        fail("builtin", "SET_BRACKETS n = 0 is structurally valid (BAD_VALUE comes from check_set_brackets)");
    /* unknown types, HELLO request, STOP */
    m.type = 0x7E;
    if (bproto_pack_msg(&m, p, sizeof p) != -1) fail("builtin", "pack of an unknown type");
    if (bproto_unpack_msg(0x7E, p, 0, &g) != BPROTO_NACK_UNKNOWN_TYPE) fail("builtin", "unknown type");
    m.type = BPROTO_MSG_HELLO;
    m.hello_request = 1;
    if (bproto_pack_msg(&m, p, sizeof p) != 0) fail("builtin", "HELLO request is empty");
    if (bproto_unpack_hello(p, 0, &g.u.hello) != BPROTO_NACK_BAD_LENGTH) fail("builtin", "unpack_hello of a request");
    if (bproto_unpack_stop(p, 0) != 0 || bproto_unpack_stop(p, 1) != BPROTO_NACK_BAD_LENGTH) fail("builtin", "STOP");
    /* PANEL_STATE value rule: every state <= BPROTO_PANEL_STATE_<FIELD>_MAX (4) */
    memset(&m, 0, sizeof m);
    m.u.panel_state.cam_left = 4u;
    m.u.panel_state.gnss = 4u;
    if (bproto_check_panel_state(&m.u.panel_state) != 0) fail("builtin", "PANEL_STATE states 0..4 are valid");
    m.u.panel_state.gnss = 5u;
    if (bproto_check_panel_state(&m.u.panel_state) != BPROTO_NACK_BAD_VALUE) fail("builtin", "PANEL_STATE gnss 5");
    m.u.panel_state.gnss = 0u;
    m.u.panel_state.cam_left = 5u;
    if (bproto_check_panel_state(&m.u.panel_state) != BPROTO_NACK_BAD_VALUE) fail("builtin", "PANEL_STATE cam 5");
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
    builtin_message_checks();
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
        case 'M': check_message(args); break;
        default: fail("line", line); break;
        }
    }
    if (fp != stdin) fclose(fp);
    printf("%s: %d checks, %d failures\n", failures ? "FAIL" : "PASS", checks, failures);
    return failures ? 1 : 0;
}
